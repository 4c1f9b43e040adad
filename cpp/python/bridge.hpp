// nrmicp's pybind11 bridge, shared by the core module (_core, module.cpp) and the PETSc engine's
// (_petsc, petsc_module.cpp): conversion of arrays, ζ, callbacks and results, and GIL handling.
// No numerics here.
#pragma once

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <nrmicp/result.hpp>
#include <nrmicp/zeta.hpp>
#include <nrmicp/detail/stopping.hpp>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <exception>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>
#if defined(__GLIBCXX__)
#include <cxxabi.h>
#endif

namespace nrmicp::bridge {

namespace py = pybind11;

template <typename I>
using CsrMap = Eigen::Map<const Eigen::SparseMatrix<double, Eigen::RowMajor, I>>;

// dst = an owned copy of the mapped (compressed) CSR matrix M, allocated to its size. Eigen 3.4
// assigns a Map entry by entry into storage that doubles as it fills: slower, and up to twice
// the memory, kept (2D obstacle n = 10^6, amg: 43 MB more peak memory).
template <typename I>
void copy_csr(const CsrMap<I>& M, Eigen::SparseMatrix<double, Eigen::RowMajor, I>& dst) {
  dst.resize(M.rows(), M.cols());
  dst.resizeNonZeros(M.nonZeros());
  std::copy_n(M.outerIndexPtr(), M.outerSize() + 1, dst.outerIndexPtr());
  std::copy_n(M.innerIndexPtr(), M.nonZeros(), dst.innerIndexPtr());
  std::copy_n(M.valuePtr(), M.nonZeros(), dst.valuePtr());
}

// dtypes compare by kind, size and byte order (np.longlong is int64; metadata is ignored).
template <typename T>
bool has_dtype(const py::array& a) {
  return a.dtype().equal(py::dtype::of<T>());
}

template <typename T>
const T* checked_data(const py::array& a, const char* what) {
  if (!has_dtype<T>(a))
    throw py::type_error(std::string(what) + " has dtype " + std::string(py::str(a.dtype())) + ", expected " +
                         std::string(py::str(py::dtype::of<T>())));
  if (a.ndim() != 1 || !(a.flags() & py::array::c_style))
    throw py::value_error(std::string(what) + " must be a contiguous 1-D array");
  return static_cast<const T*>(a.data());
}

inline Eigen::VectorXd to_vector(const py::array& a, const char* what) {
  const double* p = checked_data<double>(a, what);
  return Eigen::Map<const Eigen::VectorXd>(p, a.shape(0));
}

// Takes the GIL back after without_gil(). In a finalizing interpreter this ends the thread
// (pthread_exit: a forced unwind); a pending error holding Python objects is then leaked on
// purpose, as freeing it would need the GIL that this thread can no longer take.
inline void take_gil_back(PyThreadState* state, std::exception_ptr& error) {
#if defined(__GLIBCXX__)
  try {
    PyEval_RestoreThread(state);
  } catch (abi::__forced_unwind&) {
    new std::exception_ptr(std::move(error));  // leaked: see above
    throw;
  }
#else
  PyEval_RestoreThread(state);
#endif
}

// Runs f() with the GIL released. Not an RAII guard such as py::gil_scoped_release: taking the
// GIL back in a finalizing interpreter (a daemon thread still solving at exit) ends the thread
// by a forced unwind, which must not start inside a destructor (std::terminate: SIGABRT at exit).
template <typename F>
auto without_gil(F&& f) -> decltype(f()) {
  std::optional<decltype(f())> out;
  std::exception_ptr error;
  PyThreadState* state = PyEval_SaveThread();
  try {
    out.emplace(f());
#if defined(__GLIBCXX__)
  } catch (abi::__forced_unwind&) {
    throw;  // f() took the GIL in a finalizing interpreter: the thread is ending
#endif
  } catch (...) {
    error = std::current_exception();
  }
  take_gil_back(state, error);
  if (error) std::rethrow_exception(error);
  return std::move(*out);
}

// ζ given by a Python callable, as an nrmicp._zeta.CheckedZeta: its `fn` is called with the GIL
// taken, on a read-only float64 array allocated once per solve (ζ must not keep it: its contents
// change every iteration). A float64 vector of length n is copied as is; anything else goes to
// CheckedZeta.output, which converts it or raises naming zeta (the rules live there only).
struct CallableZeta {
  py::object checked, fn;
  std::shared_ptr<py::array_t<double>> zbuf;
  bool finite;  // checked.finite: a non-finite result at a finite z goes to output() too, which raises (ζ, ζ′'s products)

  explicit CallableZeta(py::object z)
      : checked(z), fn(z.attr("fn")), zbuf(std::make_shared<py::array_t<double>>()),
        finite(py::getattr(z, "finite", py::bool_(false)).cast<bool>()) {}

  bool operator()(const double* z, double* out, Eigen::Index n) {
    py::gil_scoped_acquire gil;
    if (zbuf->size() != n) {
      *zbuf = py::array_t<double>(n);
      py::detail::array_proxy(zbuf->ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
    }
    std::memcpy(const_cast<double*>(zbuf->data()), z, sizeof(double) * n);
    py::object r;
    try {
      r = fn(*zbuf);
    } catch (py::error_already_set& e) {
      if (!e.matches(PyExc_ValueError)) throw;
      py::object msg = checked.attr("read_only_message")(e.value());  // a write into z names zeta
      if (msg.is_none()) throw;
      py::raise_from(e, PyExc_ValueError, msg.cast<std::string>().c_str());
      throw py::error_already_set();
    }
    if (!is_vector<double>(r, n)) r = checked.attr("output")(r);
    std::memcpy(out, py::array(r).data(), sizeof(double) * n);
    if (finite && !Eigen::Map<const Eigen::VectorXd>(out, n).allFinite()) {
      if (Eigen::Map<const Eigen::VectorXd>(z, n).allFinite()) checked.attr("output")(r);  // raises, naming the call
      return false;  // (at a non-finite z the iteration failed, not the call: the core judges it)
    }
    return true;  // (else output() let it through: a run-away iterate's NaN, the core's ZetaFailed)
  }

  template <typename T>
  static bool is_vector(const py::object& r, Eigen::Index n) {
    if (!py::isinstance<py::array>(r)) return false;
    const auto a = py::reinterpret_borrow<py::array>(r);
    return has_dtype<T>(a) && a.ndim() == 1 && a.shape(0) == n && (a.flags() & py::array::c_style);
  }
};

// ∂ζ given by a Python callable (_newton.jacobian_argument's wrapper) returning either canonical
// CSR arrays (indptr, indices, data) with the index type I (the Python layer converts the user's
// matrix), or, for a linear operator, its checked product (_newton.JacobianProduct: fn and output,
// as a CheckedZeta), applied with the GIL taken only around each call on a buffer reused within
// the step. The Python objects live in `state`, owned by the Zeta (destroyed with the GIL held);
// the core's copies of the product hold only the shared pointer.
template <typename I>
struct CallableJacobian {
  struct State {
    py::object fn;
    std::optional<CallableZeta> product;  // of the last call (replaced with the GIL taken)
  };
  std::shared_ptr<State> state;

  explicit CallableJacobian(py::object fn) : state(std::make_shared<State>()) { state->fn = std::move(fn); }

  bool operator()(const Eigen::VectorXd& z, typename nrmicp::Zeta<I>::Derivative& d) {
    py::gil_scoped_acquire gil;
    const py::object r = state->fn(py::array_t<double>(z.size(), z.data()));
    if (!py::isinstance<py::tuple>(r)) {
      state->product.emplace(r);  // (a JacobianProduct: finite)
      d.product = [s = state](const double* v, double* out, Eigen::Index n) { return (*s->product)(v, out, n); };
      return true;
    }
    d.product = nullptr;
    const py::tuple t = r.cast<py::tuple>();
    const py::array ip = t[0].cast<py::array>(), ix = t[1].cast<py::array>(), dv = t[2].cast<py::array>();
    const Eigen::Index n = z.size();
    if (ip.shape(0) != n + 1) throw py::value_error("zeta_jacobian(z) must return an n-by-n matrix");
    copy_csr(CsrMap<I>(n, n, dv.shape(0), checked_data<I>(ip, "zeta_jacobian.indptr"),
                       checked_data<I>(ix, "zeta_jacobian.indices"), checked_data<double>(dv, "zeta_jacobian.data")),
             d.matrix);
    return true;
  }
};

// ζ from the Python layer's (kind, c, B, fn): none, constant c, Affine(B, c) or a callable
// (with its Jacobian when given).
template <typename I>
nrmicp::Zeta<I> make_zeta(Eigen::Index n, nrmicp::ZetaKind kind, py::object zeta_c, py::object b_indptr,
                          py::object b_indices, py::object b_data, py::object zeta_fn,
                          py::object jacobian_fn = py::none()) {
  using Z = nrmicp::Zeta<I>;
  switch (kind) {
    case nrmicp::ZetaKind::None: return Z::none();
    case nrmicp::ZetaKind::Constant: return Z::constant(to_vector(zeta_c.cast<py::array>(), "zeta"));
    case nrmicp::ZetaKind::Affine: {
      py::array bp = b_indptr.cast<py::array>(), bi = b_indices.cast<py::array>(), bd = b_data.cast<py::array>();
      CsrMap<I> B(n, n, bd.shape(0), checked_data<I>(bp, "zeta.B.indptr"), checked_data<I>(bi, "zeta.B.indices"),
                  checked_data<double>(bd, "zeta.B.data"));
      typename Z::RowMatrix owned;
      copy_csr(B, owned);
      return Z::affine(owned, to_vector(zeta_c.cast<py::array>(), "zeta.c"));
    }
    case nrmicp::ZetaKind::Functor: {
      typename Z::Differential jac;
      if (!jacobian_fn.is_none()) jac = CallableJacobian<I>(jacobian_fn);
      return Z::functor(CallableZeta(zeta_fn), jac);
    }
  }
  throw py::value_error("unknown zeta kind");
}

/// ζ with the upper bound `upper`: None (none), a float64 vector (constant), or an implicit one as
/// make_zeta's arguments (kind, c, B-indptr, B-indices, B-data, fn) from _bounds.core_upper (n: its
/// length; an engine that takes no implicit upper bound passes none).
template <typename I>
nrmicp::Zeta<I> with_upper(nrmicp::Zeta<I> zeta, const py::object& upper, Eigen::Index n = -1) {
  if (upper.is_none()) return zeta;
  if (!py::isinstance<py::tuple>(upper)) return zeta.with_upper(to_vector(upper.cast<py::array>(), "upper"));
  if (n < 0) throw py::value_error("upper: an implicit upper bound (Affine or callable) is not available here");
  const py::tuple t = upper.cast<py::tuple>();
  return zeta.with_upper(make_zeta<I>(n, t[0].cast<nrmicp::ZetaKind>(), t[1], t[2], t[3], t[4], t[5]));
}

using CoreCallback = std::function<bool(int, const Eigen::VectorXd&, double)>;

// The Python callback (k, z, Res) -> bool, called with the GIL taken; empty when None.
inline CoreCallback make_callback(const py::object& callback) {
  if (callback.is_none()) return {};
  return [&callback](int k, const Eigen::VectorXd& z, double res) -> bool {
    py::gil_scoped_acquire gil;
    return callback(k, py::array_t<double>(z.size(), z.data()), res).template cast<bool>();
  };
}

// Ctrl-C: raise KeyboardInterrupt out of the C++ loop.
inline void poll_signals() {
  py::gil_scoped_acquire gil;
  if (PyErr_CheckSignals() != 0) throw py::error_already_set();
}

// The verbose report (called every `verbose` seconds, not per iteration): the GIL only around it.
// Captures a borrowed handle: the std::function is copied without the GIL (the Monitor keeps a
// copy), so it must not own a Python reference; the caller's argument outlives the solve.
inline nrmicp::detail::Progress make_progress(const py::object& progress) {
  if (progress.is_none()) return {};
  return [h = py::handle(progress)](int k, double res, double best, double seconds, const std::string& message) {
    py::gil_scoped_acquire gil;
    h(k, res, best, seconds, message);
  };
}

// The phases' seconds by name (result.hpp's Timings).
inline py::dict timings_dict(const nrmicp::Timings& tm) {
  py::dict t;
  t["setup"] = tm.setup;
  t["factorization"] = tm.factorization;
  t["iterations"] = tm.iterations;
  t["zeta"] = tm.zeta;
  t["spmv"] = tm.spmv;
  t["inner_solve"] = tm.inner_solve;
  t["total"] = tm.total;
  return t;
}

inline py::dict result_dict(const nrmicp::Result& r, bool record_history) {
  py::dict d;
  d["z"] = py::array_t<double>(r.z.size(), r.z.data());
  d["w"] = py::array_t<double>(r.w.size(), r.w.data());
  d["status"] = static_cast<int>(r.status);
  d["message"] = r.message;
  d["nit"] = r.nit;
  d["iterations"] = r.iterations;
  d["residual"] = r.residual;
  d["inner"] = r.inner;
  d["counters"] = r.counters;  // what a step kind counts beyond iterations
  if (record_history) {
    py::dict h;
    h["iteration"] = py::array_t<int>(r.history_iteration.size(), r.history_iteration.data());
    h["seconds"] = py::array_t<double>(r.history_seconds.size(), r.history_seconds.data());
    h["residual"] = py::array_t<double>(r.history_residual.size(), r.history_residual.data());
    d["history"] = h;
  } else {
    d["history"] = py::none();
  }
  d["timings"] = timings_dict(r.timings);
  d["newton"] = r.newton;  // the Newton member's statistics (bound NewtonStats; empty for the others)
  return d;
}


}  // namespace nrmicp::bridge
