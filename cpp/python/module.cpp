// nrmicp._core — the pybind11 bridge. Conversion and GIL handling only: no numerics here.
// A is mapped zero-copy over scipy's CSR arrays (the Python layer guarantees canonical
// float64 CSR with int32/int64 indices); the arrays are kept alive by the solver object.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <nrmicp/nrmicp.hpp>

#include <cstdint>
#include <cstring>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace py = pybind11;
using nrmicp::Options;

namespace {

template <typename I>
using CsrMap = Eigen::Map<const Eigen::SparseMatrix<double, Eigen::RowMajor, I>>;

template <typename T>
const T* checked_data(const py::array& a, const char* what) {
  if (!a.dtype().is(py::dtype::of<T>()))
    throw py::type_error(std::string(what) + " has dtype " + std::string(py::str(a.dtype())) + ", expected " +
                         std::string(py::str(py::dtype::of<T>())));
  if (a.ndim() != 1 || !(a.flags() & py::array::c_style))
    throw py::value_error(std::string(what) + " must be a contiguous 1-D array");
  return static_cast<const T*>(a.data());
}

Eigen::VectorXd to_vector(const py::array& a, const char* what) {
  const double* p = checked_data<double>(a, what);
  return Eigen::Map<const Eigen::VectorXd>(p, a.shape(0));
}

// ζ given by a Python callable: called with the GIL taken, on a read-only float64 array that
// is allocated once per solve (ζ must not keep it: its contents change every iteration).
struct CallableZeta {
  py::object fn;
  std::shared_ptr<py::array_t<double>> zbuf;

  bool operator()(const double* z, double* out, Eigen::Index n) {
    py::gil_scoped_acquire gil;
    if (zbuf->size() != n) {
      *zbuf = py::array_t<double>(n);
      py::detail::array_proxy(zbuf->ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
    }
    std::memcpy(const_cast<double*>(zbuf->data()), z, sizeof(double) * n);
    py::object r = fn(*zbuf);
    if (py::isinstance<py::array>(r)) {
      const char kind = py::array(r).dtype().kind();
      if (kind != 'f' && kind != 'i' && kind != 'u')
        throw py::type_error("zeta(z) returned an array of dtype " + std::string(py::str(py::array(r).dtype())) +
                             "; expected a real floating-point array of shape (" + std::to_string(n) + ",)");
    }
    auto arr = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(r);
    if (!arr)
      throw py::type_error("zeta(z) must return a float64 array of shape (" + std::to_string(n) + ",), got " +
                           std::string(py::str(py::type::of(r).attr("__name__"))));
    if (arr.ndim() != 1 || arr.shape(0) != n) {
      std::string shape = "(";
      for (py::ssize_t d = 0; d < arr.ndim(); ++d) shape += std::to_string(arr.shape(d)) + (d + 1 < arr.ndim() ? ", " : "");
      shape += arr.ndim() == 1 ? ",)" : ")";
      throw py::value_error("zeta(z) must return an array of shape (" + std::to_string(n) + ",), got shape " + shape);
    }
    std::memcpy(out, arr.data(), sizeof(double) * n);
    return true;  // finiteness is checked by the core (status ZetaFailed)
  }
};

// ∂ζ given by a Python callable returning canonical CSR arrays (indptr, indices, data) with the
// index type I (the Python layer converts the user's matrix); called with the GIL taken.
template <typename I>
struct CallableJacobian {
  py::object fn;
  bool operator()(const Eigen::VectorXd& z, typename nrmicp::Zeta<I>::RowMatrix& J) {
    py::gil_scoped_acquire gil;
    const py::tuple t = fn(py::array_t<double>(z.size(), z.data())).template cast<py::tuple>();
    const py::array ip = t[0].cast<py::array>(), ix = t[1].cast<py::array>(), dv = t[2].cast<py::array>();
    const Eigen::Index n = z.size();
    if (ip.shape(0) != n + 1) throw py::value_error("zeta_jacobian(z) must return an n-by-n matrix");
    J = CsrMap<I>(n, n, dv.shape(0), checked_data<I>(ip, "zeta_jacobian.indptr"),
                  checked_data<I>(ix, "zeta_jacobian.indices"), checked_data<double>(dv, "zeta_jacobian.data"));
    return true;
  }
};

// ζ from the Python layer's (kind, c, B, fn): 0 none, 1 constant c, 2 Affine(B, c), 3 callable.
template <typename I>
nrmicp::Zeta<I> make_zeta(Eigen::Index n, int zeta_kind, py::object zeta_c, py::object b_indptr, py::object b_indices,
                          py::object b_data, py::object zeta_fn, py::object jacobian_fn = py::none()) {
  using Z = nrmicp::Zeta<I>;
  switch (zeta_kind) {
    case 0: return Z::none();
    case 1: return Z::constant(to_vector(zeta_c.cast<py::array>(), "zeta"));
    case 2: {
      py::array bp = b_indptr.cast<py::array>(), bi = b_indices.cast<py::array>(), bd = b_data.cast<py::array>();
      CsrMap<I> B(n, n, bd.shape(0), checked_data<I>(bp, "zeta.B.indptr"), checked_data<I>(bi, "zeta.B.indices"),
                  checked_data<double>(bd, "zeta.B.data"));
      return Z::affine(typename Z::RowMatrix(B), to_vector(zeta_c.cast<py::array>(), "zeta.c"));
    }
    case 3: {
      typename Z::Jacobian jac;
      if (!jacobian_fn.is_none()) jac = CallableJacobian<I>{jacobian_fn};
      return Z::functor(CallableZeta{zeta_fn, std::make_shared<py::array_t<double>>()}, jac);
    }
    default: throw py::value_error("unknown zeta kind");
  }
}

using CoreCallback = std::function<bool(int, const Eigen::VectorXd&, double)>;

// The Python callback (k, z, Res) -> bool, called with the GIL taken; empty when None.
CoreCallback make_callback(const py::object& callback) {
  if (callback.is_none()) return {};
  return [&callback](int k, const Eigen::VectorXd& z, double res) -> bool {
    py::gil_scoped_acquire gil;
    return callback(k, py::array_t<double>(z.size(), z.data()), res).template cast<bool>();
  };
}

// Ctrl-C: raise KeyboardInterrupt out of the C++ loop.
void poll_signals() {
  py::gil_scoped_acquire gil;
  if (PyErr_CheckSignals() != 0) throw py::error_already_set();
}

py::dict result_dict(const nrmicp::Result& r, bool record_history) {
  py::dict d;
  d["z"] = py::array_t<double>(r.z.size(), r.z.data());
  d["w"] = py::array_t<double>(r.w.size(), r.w.data());
  d["status"] = static_cast<int>(r.status);
  d["message"] = r.message;
  d["nit"] = r.nit;
  d["iterations"] = r.iterations;
  d["residual"] = r.residual;
  d["inner"] = r.inner;
  if (record_history) {
    py::dict h;
    h["iteration"] = py::array_t<int>(r.history_iteration.size(), r.history_iteration.data());
    h["seconds"] = py::array_t<double>(r.history_seconds.size(), r.history_seconds.data());
    h["residual"] = py::array_t<double>(r.history_residual.size(), r.history_residual.data());
    d["history"] = h;
  } else {
    d["history"] = py::none();
  }
  py::dict t;
  t["setup"] = r.timings.setup;
  t["factorization"] = r.timings.factorization;
  t["iterations"] = r.timings.iterations;
  t["zeta"] = r.timings.zeta;
  t["spmv"] = r.timings.spmv;
  t["inner_solve"] = r.timings.inner_solve;
  t["total"] = r.timings.total;
  d["timings"] = t;
  // the Newton member (empty for the stationary members)
  d["linear_solves"] = r.linear_solves;
  d["fallback_sweeps"] = r.fallback_sweeps;
  d["outer_iterations"] = r.outer_iterations;
  d["level_steps"] = r.level_steps;
  d["level_seconds"] = r.level_seconds;
  d["path"] = r.path;
  return d;
}

template <typename I>
class PySolver {
 public:
  PySolver(py::array indptr, py::array indices, py::array data, Eigen::Index n)
      : indptr_(indptr), indices_(indices), data_(data),
        A_(n, n, data.shape(0), checked_data<I>(indptr, "A.indptr"), checked_data<I>(indices, "A.indices"),
           checked_data<double>(data, "A.data")) {
    if (indptr.shape(0) != n + 1) throw py::value_error("A.indptr must have length n + 1");
    if (indices.shape(0) != data.shape(0)) throw py::value_error("A.indices and A.data differ in length");
  }
  void build(const Options& o) { solver_.emplace(A_, o); }

  py::dict solve(py::array q, int zeta_kind, py::object zeta_c, py::object b_indptr, py::object b_indices,
                 py::object b_data, py::object zeta_fn, py::object z0, py::object callback, const Options& it) {
    const Eigen::Index n = A_.rows();
    Eigen::VectorXd qv = to_vector(q, "q");
    std::optional<Eigen::VectorXd> z0v;
    if (!z0.is_none()) z0v = to_vector(z0.cast<py::array>(), "x0");
    const auto zeta = make_zeta<I>(n, zeta_kind, zeta_c, b_indptr, b_indices, b_data, zeta_fn);
    const auto cb = make_callback(callback);
    nrmicp::Result r;
    {
      py::gil_scoped_release release;
      r = solver_->solve(qv, zeta, z0v ? &*z0v : nullptr, cb, poll_signals, &it);
    }
    return result_dict(r, it.record_history);
  }

  py::dict parameters() const {
    const auto& p = solver_->parameters();
    py::dict d;
    d["omega1"] = p.omega1; d["omega2"] = p.omega2; d["phi"] = p.phi;
    d["gamma"] = p.gamma; d["alpha"] = p.alpha; d["beta"] = p.beta;
    d["inner"] = std::string(solver_->inner_name());
    return d;
  }

 private:
  py::array indptr_, indices_, data_;  // A_ maps these
  CsrMap<I> A_;
  std::optional<nrmicp::Solver<CsrMap<I>>> solver_;
};

template <typename I>
void bind_solver(py::module_& m, const char* name) {
  py::class_<PySolver<I>>(m, name)
      .def(py::init([](py::array indptr, py::array indices, py::array data, Eigen::Index n, const Options& o) {
             auto s = std::make_unique<PySolver<I>>(indptr, indices, data, n);
             py::gil_scoped_release release;  // factorization may take a while
             s->build(o);
             return s;
           }),
           py::arg("indptr"), py::arg("indices"), py::arg("data"), py::arg("n"), py::arg("options"))
      .def("solve", &PySolver<I>::solve, py::arg("q"), py::arg("zeta_kind"), py::arg("zeta_c"), py::arg("b_indptr"),
           py::arg("b_indices"), py::arg("b_data"), py::arg("zeta_fn"), py::arg("x0"), py::arg("callback"),
           py::arg("options"))
      .def("parameters", &PySolver<I>::parameters);
}

// The Newton member: A mapped as for PySolver; prolongations as a list of CSR triples
// (indptr, indices, data, rows, cols) with A's index type, copied into the core.
template <typename I>
class PyNewton {
 public:
  using Core = nrmicp::Newton<CsrMap<I>>;
  PyNewton(py::array indptr, py::array indices, py::array data, Eigen::Index n)
      : indptr_(indptr), indices_(indices), data_(data),
        A_(n, n, data.shape(0), checked_data<I>(indptr, "A.indptr"), checked_data<I>(indices, "A.indices"),
           checked_data<double>(data, "A.data")) {
    if (indptr.shape(0) != n + 1) throw py::value_error("A.indptr must have length n + 1");
    if (indices.shape(0) != data.shape(0)) throw py::value_error("A.indices and A.data differ in length");
  }
  static std::vector<typename Core::RowMatrix> prolongations(const py::list& ps) {
    std::vector<typename Core::RowMatrix> out;
    for (std::size_t l = 0; l < ps.size(); ++l) {
      const auto t = ps[l].cast<py::tuple>();
      const std::string name = "prolongations[" + std::to_string(l) + "]";
      py::array ip = t[0].cast<py::array>(), ix = t[1].cast<py::array>(), dv = t[2].cast<py::array>();
      const auto rows = t[3].cast<Eigen::Index>(), cols = t[4].cast<Eigen::Index>();
      if (ip.shape(0) != rows + 1) throw py::value_error(name + ".indptr must have length rows + 1");
      CsrMap<I> P(rows, cols, dv.shape(0), checked_data<I>(ip, (name + ".indptr").c_str()),
                  checked_data<I>(ix, (name + ".indices").c_str()), checked_data<double>(dv, (name + ".data").c_str()));
      out.emplace_back(P);
    }
    return out;
  }
  void build(const Options& o, std::vector<typename Core::RowMatrix> P) { newton_.emplace(A_, o, std::move(P)); }

  py::dict solve(py::array q, int zeta_kind, py::object zeta_c, py::object b_indptr, py::object b_indices,
                 py::object b_data, py::object zeta_fn, py::object z0, py::object callback, const Options& it,
                 py::object zeta_jacobian) {
    const Eigen::Index n = A_.rows();
    Eigen::VectorXd qv = to_vector(q, "q");
    std::optional<Eigen::VectorXd> z0v;
    if (!z0.is_none()) z0v = to_vector(z0.cast<py::array>(), "x0");
    const auto zeta = make_zeta<I>(n, zeta_kind, zeta_c, b_indptr, b_indices, b_data, zeta_fn, zeta_jacobian);
    const auto cb = make_callback(callback);
    nrmicp::Result r;
    {
      py::gil_scoped_release release;
      r = newton_->solve(qv, zeta, z0v ? &*z0v : nullptr, cb, poll_signals, &it);
    }
    return result_dict(r, it.record_history);
  }
  // One Newton step from z (polish).
  py::dict polish(py::array q, int zeta_kind, py::object zeta_c, py::object b_indptr, py::object b_indices,
                  py::object b_data, py::object zeta_fn, py::array z, double tol) {
    const Eigen::Index n = A_.rows();
    Eigen::VectorXd qv = to_vector(q, "q"), zv = to_vector(z, "z");
    const auto zeta = make_zeta<I>(n, zeta_kind, zeta_c, b_indptr, b_indices, b_data, zeta_fn);
    nrmicp::Result r;
    {
      py::gil_scoped_release release;
      r = newton_->polish(qv, zeta, zv, tol);
    }
    return result_dict(r, false);
  }
  int levels() const { return newton_->levels(); }
  py::dict parameters() const {
    const auto& p = newton_->parameters();
    py::dict d;
    d["omega1"] = p.omega1; d["omega2"] = p.omega2; d["gamma"] = p.gamma;
    d["inner"] = std::string(newton_->inner_name());
    return d;
  }

 private:
  py::array indptr_, indices_, data_;  // A_ maps these
  CsrMap<I> A_;
  std::optional<Core> newton_;
};

template <typename I>
void bind_newton(py::module_& m, const char* name) {
  py::class_<PyNewton<I>>(m, name)
      .def(py::init([](py::array indptr, py::array indices, py::array data, Eigen::Index n, const Options& o,
                       const py::list& prolongations) {
             auto s = std::make_unique<PyNewton<I>>(indptr, indices, data, n);
             auto P = PyNewton<I>::prolongations(prolongations);
             py::gil_scoped_release release;  // coarse operators PᵀAP
             s->build(o, std::move(P));
             return s;
           }),
           py::arg("indptr"), py::arg("indices"), py::arg("data"), py::arg("n"), py::arg("options"),
           py::arg("prolongations"))
      .def("solve", &PyNewton<I>::solve, py::arg("q"), py::arg("zeta_kind"), py::arg("zeta_c"), py::arg("b_indptr"),
           py::arg("b_indices"), py::arg("b_data"), py::arg("zeta_fn"), py::arg("x0"), py::arg("callback"),
           py::arg("options"), py::arg("zeta_jacobian") = py::none())
      .def("polish", &PyNewton<I>::polish, py::arg("q"), py::arg("zeta_kind"), py::arg("zeta_c"),
           py::arg("b_indptr"), py::arg("b_indices"), py::arg("b_data"), py::arg("zeta_fn"), py::arg("z"), py::arg("tol"))
      .def_property_readonly("levels", &PyNewton<I>::levels)
      .def("parameters", &PyNewton<I>::parameters);
}

// Sorted column indices without duplicates in every row, and indptr consistent with them.
template <typename I>
bool csr_is_canonical(const py::array& indptr, const py::array& indices) {
  const I* p = checked_data<I>(indptr, "A.indptr");
  const I* j = checked_data<I>(indices, "A.indices");
  const py::ssize_t rows = indptr.shape(0) - 1, nnz = indices.shape(0);
  if (rows < 0 || p[0] != 0 || p[rows] != nnz) return false;
  for (py::ssize_t r = 0; r < rows; ++r) {
    if (p[r + 1] < p[r]) return false;
    for (I k = p[r] + 1; k < p[r + 1]; ++k)
      if (j[k] <= j[k - 1]) return false;
  }
  return true;
}

}  // namespace

PYBIND11_MODULE(_core, m) {
  m.doc() = "nrmicp C++ core (internal: use the nrmicp package)";
  py::enum_<nrmicp::Method>(m, "Method")
      .value("nrm", nrmicp::Method::NRM).value("nrmm", nrmicp::Method::NRMM)
      .value("nrmaor", nrmicp::Method::NRMAOR).value("nrmsor", nrmicp::Method::NRMSOR)
      .value("nrmgs", nrmicp::Method::NRMGS).value("nrmj", nrmicp::Method::NRMJ)
      .value("mms", nrmicp::Method::MMS).value("two_sweep", nrmicp::Method::TwoSweep)
      .value("newton", nrmicp::Method::Newton);
  py::enum_<nrmicp::ZUpdate>(m, "ZUpdate")
      .value("auto", nrmicp::ZUpdate::Auto).value("explicit", nrmicp::ZUpdate::Explicit)
      .value("solve", nrmicp::ZUpdate::Solve);
  py::enum_<nrmicp::Inner>(m, "Inner")
      .value("auto", nrmicp::Inner::Auto).value("cholmod", nrmicp::Inner::Cholmod)
      .value("umfpack", nrmicp::Inner::Umfpack).value("eigen_llt", nrmicp::Inner::EigenLLT)
      .value("eigen_lu", nrmicp::Inner::EigenLU);
  py::enum_<nrmicp::Accelerate>(m, "Accelerate")
      .value("none", nrmicp::Accelerate::None).value("anderson", nrmicp::Accelerate::Anderson);

  py::class_<Options>(m, "Options")
      .def(py::init<>())
      .def_readwrite("method", &Options::method)
      .def_readwrite("tol", &Options::tol)
      .def_readwrite("maxiter", &Options::maxiter)
      .def_readwrite("omega1", &Options::omega1)
      .def_readwrite("omega2", &Options::omega2)
      .def_readwrite("gamma", &Options::gamma)
      .def_readwrite("phi", &Options::phi)
      .def_readwrite("alpha", &Options::alpha)
      .def_readwrite("beta", &Options::beta)
      .def_readwrite("theta", &Options::theta)
      .def_readwrite("z_update", &Options::z_update)
      .def_readwrite("inner", &Options::inner)
      .def_readwrite("accelerate", &Options::accelerate)
      .def_readwrite("anderson_m", &Options::anderson_m)
      .def_readwrite("record_history", &Options::record_history)
      .def_readwrite("stall_iterations", &Options::stall_iterations)
      .def_readwrite("divergence_factor", &Options::divergence_factor)
      .def("check", &Options::check, py::arg("n"));

  bind_solver<std::int32_t>(m, "SolverI32");
  bind_solver<std::int64_t>(m, "SolverI64");
  bind_newton<std::int32_t>(m, "NewtonI32");
  bind_newton<std::int64_t>(m, "NewtonI64");

  m.def("csr_is_canonical", [](const py::array& indptr, const py::array& indices) {
    return indices.dtype().is(py::dtype::of<std::int64_t>()) ? csr_is_canonical<std::int64_t>(indptr, indices)
                                                              : csr_is_canonical<std::int32_t>(indptr, indices);
  });
  m.def("backends", [] {
    py::dict d;
    d["cholmod"] = nrmicp::have_cholmod();
    d["umfpack"] = nrmicp::have_umfpack();
    d["eigen_llt"] = true;
    d["eigen_lu"] = true;
    return d;
  });
}
