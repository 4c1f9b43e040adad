// nrmicp._core — the pybind11 bridge. Conversion and GIL handling only: no numerics here.
// A is mapped zero-copy over scipy's CSR arrays (the Python layer guarantees canonical
// float64 CSR with int32/int64 indices); the arrays are kept alive by the solver object.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <nrmicp/nrmicp.hpp>
#include <nrmicp/detail/interpolation.hpp>

#include "bridge.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>
#if defined(__GLIBCXX__)
#include <cxxabi.h>
#endif

namespace py = pybind11;
using nrmicp::Options;
using nrmicp::SolveOptions;

namespace {

using namespace nrmicp::bridge;

// A mapped zero-copy over scipy's CSR arrays, which it keeps alive (the cores hold references
// to the map). Checked here for what the map itself reads; the rest of the structure (monotone
// indptr, indices in range) was checked by check_compressed in the Python layer.
template <typename I>
struct MappedCsr {
  py::array indptr, indices, data;
  CsrMap<I> A;
  MappedCsr(py::array ip, py::array ix, py::array dv, Eigen::Index n)
      : indptr(ip), indices(ix), data(dv),
        A(n, n, dv.shape(0), checked_data<I>(ip, "A.indptr"), checked_data<I>(ix, "A.indices"),
          checked_data<double>(dv, "A.data")) {
    if (ip.shape(0) != n + 1) throw py::value_error("A.indptr must have length n + 1");
    if (ix.shape(0) != dv.shape(0)) throw py::value_error("A.indices and A.data differ in length");
    if (A.outerIndexPtr()[0] != 0 || A.outerIndexPtr()[n] != dv.shape(0))
      throw py::value_error("A.indptr must run from 0 to nnz = len(A.data)");
  }
};

// What PySolver and PyNewton share: A mapped zero-copy, the core, and the solve.
template <typename I, typename Core>
class PyCore {
 public:
  PyCore(py::array indptr, py::array indices, py::array data, Eigen::Index n) : A_(indptr, indices, data, n) {}

  py::dict solve(py::array q, nrmicp::ZetaKind zeta_kind, py::object zeta_c, py::object b_indptr,
                 py::object b_indices, py::object b_data, py::object zeta_fn, py::object z0, py::object callback,
                 const SolveOptions& it, py::object zeta_jacobian, py::object progress, py::object upper) {
    const Eigen::Index n = A_.A.rows();
    Eigen::VectorXd qv = to_vector(q, "q");
    std::optional<Eigen::VectorXd> z0v;
    if (!z0.is_none()) z0v = to_vector(z0.cast<py::array>(), "x0");
    const auto zeta =
        with_upper(make_zeta<I>(n, zeta_kind, zeta_c, b_indptr, b_indices, b_data, zeta_fn, zeta_jacobian), upper, n);
    const auto cb = make_callback(callback);
    const auto report = make_progress(progress);
    nrmicp::Result r =
        without_gil([&] { return core_->solve(qv, zeta, z0v ? &*z0v : nullptr, cb, poll_signals, &it, report); });
    return result_dict(r, it.record_history);
  }
  /// The constructor's seconds (setup, and the factorization part of it).
  py::dict setup_timings() const { return timings_dict(core_->setup_timings()); }

  /// The solve's arguments, for both bindings.
  template <typename Class>
  static void def_solve(Class& cls) {
    cls.def("solve", &PyCore::solve, py::arg("q"), py::arg("zeta_kind"), py::arg("zeta_c"), py::arg("b_indptr"),
            py::arg("b_indices"), py::arg("b_data"), py::arg("zeta_fn"), py::arg("x0"), py::arg("callback"),
            py::arg("options"), py::arg("zeta_jacobian") = py::none(), py::arg("progress") = py::none(),
            py::arg("upper") = py::none());
    cls.def("setup_timings", &PyCore::setup_timings);
  }

 protected:
  MappedCsr<I> A_;
  std::optional<Core> core_;
};

template <typename I>
class PySolver : public PyCore<I, nrmicp::Solver<CsrMap<I>>> {
 public:
  using PyCore<I, nrmicp::Solver<CsrMap<I>>>::PyCore;
  void build(const Options& o) { this->core_.emplace(this->A_.A, o); }

  py::dict parameters() const {
    const auto& p = this->core_->parameters();
    py::dict d;
    d["omega1"] = p.omega1; d["omega2"] = p.omega2; d["phi"] = p.phi;
    d["gamma"] = p.gamma; d["alpha"] = p.alpha; d["beta"] = p.beta;
    d["inner"] = std::string(this->core_->inner_name());
    return d;
  }
};

template <typename I>
void bind_solver(py::module_& m, const char* name) {
  py::class_<PySolver<I>> cls(m, name);
  cls.def(py::init([](py::array indptr, py::array indices, py::array data, Eigen::Index n, const Options& o) {
             auto s = std::make_unique<PySolver<I>>(indptr, indices, data, n);
             without_gil([&] { s->build(o); return true; });  // factorization may take a while
             return s;
           }),
           py::arg("indptr"), py::arg("indices"), py::arg("data"), py::arg("n"), py::arg("options"))
      .def("parameters", &PySolver<I>::parameters);
  PySolver<I>::def_solve(cls);
}

// The Newton member: A mapped as for PySolver; prolongations as a list of CSR triples
// (indptr, indices, data, rows, cols) with A's index type, copied into the core.
template <typename I>
class PyNewton : public PyCore<I, nrmicp::Newton<CsrMap<I>>> {
 public:
  using Core = nrmicp::Newton<CsrMap<I>>;
  using PyCore<I, Core>::PyCore;
  /// (indptr, indices, data, rows, cols) triples, copied; `what` names them in errors. The list is
  /// emptied as they are copied (it is _newton.make_core's own): one copy of each level at a time.
  static std::vector<typename Core::RowMatrix> matrices(py::list ps, const char* what) {
    std::vector<typename Core::RowMatrix> out;
    out.reserve(ps.size());   // growth would copy every matrix so far (Eigen 3.4's SparseMatrix cannot move)
    for (std::size_t l = 0; l < ps.size(); ++l) {
      const auto t = ps[l].cast<py::tuple>();
      const std::string name = std::string(what) + "[" + std::to_string(l) + "]";
      py::array ip = t[0].cast<py::array>(), ix = t[1].cast<py::array>(), dv = t[2].cast<py::array>();
      const auto rows = t[3].cast<Eigen::Index>(), cols = t[4].cast<Eigen::Index>();
      if (ip.shape(0) != rows + 1) throw py::value_error(name + ".indptr must have length rows + 1");
      CsrMap<I> P(rows, cols, dv.shape(0), checked_data<I>(ip, (name + ".indptr").c_str()),
                  checked_data<I>(ix, (name + ".indices").c_str()), checked_data<double>(dv, (name + ".data").c_str()));
      copy_csr(P, out.emplace_back());
      ps[l] = py::none();
    }
    return out;
  }
  void build(const Options& o, std::vector<typename Core::RowMatrix> P, std::vector<typename Core::RowMatrix> coarse) {
    this->core_.emplace(this->A_.A, o, std::move(P), std::move(coarse));
  }

  // One Newton step from z (polish).
  py::dict polish(py::array q, nrmicp::ZetaKind zeta_kind, py::object zeta_c, py::object b_indptr,
                  py::object b_indices, py::object b_data, py::object zeta_fn, py::array z, double tol,
                  py::object upper) {
    const Eigen::Index n = this->A_.A.rows();
    Eigen::VectorXd qv = to_vector(q, "q"), zv = to_vector(z, "z");
    const auto zeta = with_upper(make_zeta<I>(n, zeta_kind, zeta_c, b_indptr, b_indices, b_data, zeta_fn), upper, n);
    nrmicp::Result r = without_gil([&] { return this->core_->polish(qv, zeta, zv, tol); });
    return result_dict(r, false);
  }
  int levels() const { return this->core_->levels(); }
  py::dict hierarchy() const {
    const nrmicp::HierarchyReport& h = this->core_->hierarchy();
    py::dict d;
    d["requested"] = h.requested; d["used"] = h.used; d["reason"] = h.reason;
    return d;
  }
  py::dict parameters() const {
    const auto& p = this->core_->parameters();
    py::dict d;
    d["omega1"] = p.omega1; d["omega2"] = p.omega2; d["gamma"] = p.gamma;
    d["inner"] = std::string(this->core_->inner_name());
    return d;
  }
};

template <typename I>
void bind_newton(py::module_& m, const char* name) {
  py::class_<PyNewton<I>> cls(m, name);
  cls.def(py::init([](py::array indptr, py::array indices, py::array data, Eigen::Index n, const Options& o,
                       py::list prolongations, py::list coarse_operators) {
             auto s = std::make_unique<PyNewton<I>>(indptr, indices, data, n);
             auto P = PyNewton<I>::matrices(prolongations, "prolongations");
             auto C = PyNewton<I>::matrices(coarse_operators, "coarse_operators");
             without_gil([&] { s->build(o, std::move(P), std::move(C)); return true; });  // coarse operators PᵀAP
             return s;
           }),
           py::arg("indptr"), py::arg("indices"), py::arg("data"), py::arg("n"), py::arg("options"),
           py::arg("prolongations"), py::arg("coarse_operators") = py::list())
      .def("polish", &PyNewton<I>::polish, py::arg("q"), py::arg("zeta_kind"), py::arg("zeta_c"),
           py::arg("b_indptr"), py::arg("b_indices"), py::arg("b_data"), py::arg("zeta_fn"), py::arg("z"), py::arg("tol"),
           py::arg("upper") = py::none())
      .def_property_readonly("levels", &PyNewton<I>::levels)
      .def_property_readonly("hierarchy", &PyNewton<I>::hierarchy,
                             "{'requested', 'used', 'reason'}: the levels given and used, why fewer ('' when none)")
      .def("parameters", &PyNewton<I>::parameters);
  PyNewton<I>::def_solve(cls);
}

template <typename E, std::size_t N, typename Name>
void bind_enum(py::module_& m, const char* name, const E (&values)[N], Name name_of) {
  py::enum_<E> e(m, name);
  for (E v : values) e.value(name_of(v), v);
}

// A compressed sparse structure (CSR: outer = rows, inner = columns; CSC the other way) checked
// before anything reads it: indptr has outer + 1 entries, starts at 0, never decreases and ends
// at nnz <= the number of stored indices and values; every index lies in [0, inner). One pass in
// 64-bit arithmetic. Throws ValueError naming `name`. Returns whether the indices are also sorted
// without duplicates in every row (canonical: nothing to sort or sum).
template <typename I>
bool check_compressed(const py::array& indptr, const py::array& indices, py::ssize_t n_data, py::ssize_t outer,
                      py::ssize_t inner, const std::string& name) {
  const I* p = checked_data<I>(indptr, (name + ".indptr").c_str());
  const I* j = checked_data<I>(indices, (name + ".indices").c_str());
  auto fail = [&](const std::string& msg) { throw py::value_error(name + " is not a valid sparse matrix: " + msg); };
  if (indptr.shape(0) != outer + 1)
    fail(name + ".indptr has length " + std::to_string(indptr.shape(0)) + ", expected " + std::to_string(outer + 1));
  const std::int64_t stored = std::min<std::int64_t>(indices.shape(0), n_data);
  if (p[0] != 0) fail(name + ".indptr[0] = " + std::to_string(p[0]) + ", expected 0");
  bool canonical = true;
  for (py::ssize_t r = 0; r < outer; ++r) {
    const std::int64_t begin = p[r], end = p[r + 1];
    if (end < begin)
      fail(name + ".indptr decreases at " + std::to_string(r + 1) + " (" + std::to_string(begin) + " -> " +
           std::to_string(end) + ")");
    if (end > stored)
      fail(name + ".indptr[" + std::to_string(r + 1) + "] = " + std::to_string(end) + " exceeds the " +
           std::to_string(stored) + " stored entries (len of " + name + ".indices and " + name + ".data)");
    for (std::int64_t k = begin; k < end; ++k) {
      const std::int64_t c = j[k];
      if (c < 0 || c >= inner)
        fail(name + ".indices[" + std::to_string(k) + "] = " + std::to_string(c) + " is outside [0, " +
             std::to_string(inner) + ")");
      if (k > begin && c <= j[k - 1]) canonical = false;
    }
  }
  return canonical;
}

// A failed factorization is the same exception at set-up and in a lazy one during solve().
void bind_exceptions() {
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const nrmicp::FactorizationError& e) {
      if (e.reason() == nrmicp::FactorizationError::Reason::OutOfMemory) {
        PyErr_SetString(PyExc_MemoryError, e.what());
      } else {
        const py::object linalg_error = py::module_::import("numpy.linalg").attr("LinAlgError");
        PyErr_SetString(linalg_error.ptr(), e.what());
      }
    }
  });
}

// The option and status vocabulary; the names come from the C++ core (options.hpp, result.hpp)
// and Python derives its lists from these.
void bind_vocabulary(py::module_& m) {
  bind_enum(m, "Method", nrmicp::all_methods, [](nrmicp::Method v) { return nrmicp::to_string(v); });
  bind_enum(m, "ZUpdate", nrmicp::all_z_updates, [](nrmicp::ZUpdate v) { return nrmicp::to_string(v); });
  bind_enum(m, "Inner", nrmicp::all_inners, [](nrmicp::Inner v) { return nrmicp::to_string(v); });
  bind_enum(m, "Accelerate", nrmicp::all_accelerations, [](nrmicp::Accelerate v) { return nrmicp::to_string(v); });
  bind_enum(m, "ZetaKind", nrmicp::all_zeta_kinds, [](nrmicp::ZetaKind v) { return nrmicp::to_string(v); });
  bind_enum(m, "Status", nrmicp::all_statuses, [](nrmicp::Status v) { return nrmicp::status_name(v); });
  m.def("status_message", [](int code) {
    for (nrmicp::Status s : nrmicp::all_statuses)
      if (static_cast<int>(s) == code) return std::string(nrmicp::to_string(s));
    throw py::value_error("unknown status code " + std::to_string(code));
  }, py::arg("code"), "What a status code means (the start of a result's message).");
  using Tuning = nrmicp::detail::NewtonTuning;
  py::dict tuning;  // the Newton member's constants, read by the Python layer and the tests
  tuning["coarse_maxiter"] = Tuning::coarse_maxiter;
  tuning["coarse_forcing"] = Tuning::coarse_forcing;
  tuning["coarse_repeat_trust"] = Tuning::coarse_repeat_trust;
  tuning["nested_first_forcing"] = Tuning::nested_first_forcing;
  tuning["nested_forcing"] = Tuning::nested_forcing;
  tuning["warm_start_fraction"] = Tuning::warm_start_fraction;
  tuning["warm_steps"] = Tuning::warm_steps;
  tuning["floor_factor"] = nrmicp::detail::kFloorFactor;
  tuning["overshoot_growth"] = nrmicp::detail::kOvershootGrowth;
  tuning["overshoot_damping"] = nrmicp::detail::kOvershootDamping;
  tuning["smoothing_sweeps"] = nrmicp::detail::kSmoothingSweeps;
  tuning["fold_density"] = nrmicp::detail::kFoldDensity;
  m.attr("newton_tuning") = tuning;
  m.attr("refused_elsewhere") = nrmicp::detail::kRefusedElsewhere;  // (nrmicp._mpi.agree prefers the first-hand message)
  m.def("is_aor_type", &nrmicp::is_aor_type, py::arg("method"),
        "True for the methods whose left matrix is triangular or diagonal (no factorization).");
  m.def("resolved_z_update", [](nrmicp::Method method, bool omega2_given, bool is_icp) {
    return std::string(nrmicp::to_string(nrmicp::resolve_z_update(nrmicp::ZUpdate::Auto, method, omega2_given, is_icp)));
  }, py::arg("method"), py::arg("omega2_given"), py::arg("is_icp"),
     "The z-update 'auto' means for this method (is_icp: a zeta that is not None or constant).");

}

// The Newton member's statistics; `fields` lists them for the Python result (by reflection).
void bind_newton_stats(py::module_& m) {
  py::class_<nrmicp::NewtonStats> stats(m, "NewtonStats");
  std::vector<std::string> stat_fields;
  auto stat = [&](const char* name, auto member) {
    stats.def_readonly(name, member);
    stat_fields.emplace_back(name);
  };
  stat("linear_solves", &nrmicp::NewtonStats::linear_solves);
  stat("inner_iterations", &nrmicp::NewtonStats::inner_iterations);
  stat("fallback_sweeps", &nrmicp::NewtonStats::fallback_sweeps);
  stat("outer_iterations", &nrmicp::NewtonStats::outer_iterations);
  stat("level_steps", &nrmicp::NewtonStats::level_steps);
  stat("level_seconds", &nrmicp::NewtonStats::level_seconds);
  stat("path", &nrmicp::NewtonStats::path);
  stats.attr("fields") = py::tuple(py::cast(stat_fields));

}

/// A field's default as Python writes it: an enum's name, None for an empty diagonal or a NaN
/// (the method's default), else the number or bool.
template <typename T>
py::object python_value(const T& v) {
  if constexpr (std::is_enum_v<T>) return py::str(nrmicp::to_string(v));
  else if constexpr (std::is_same_v<T, Eigen::VectorXd>) return py::none();
  else if constexpr (std::is_same_v<T, double>)
    return std::isnan(v) ? py::object(py::none()) : py::object(py::float_(v));
  else return py::cast(v);
}

/// One row of nrmicp::option_table as a dict: kind ('real', 'integer', 'boolean', 'choice',
/// 'diagonal', or 'python': the Python layer's own option, of type `type`), its choices, the
/// default of nrmicp.solve's keyword and the C++ field's (core_default).
py::dict option_row(const nrmicp::OptionSpec& spec) {
  static const Options defaults;
  static const char* scopes[] = {"setup", "solve", "call"};
  py::dict d;
  d["name"] = spec.name;
  d["scope"] = scopes[static_cast<int>(spec.scope)];
  d["doc"] = spec.doc;
  d["python"] = spec.python;
  d["type"] = spec.python_type ? py::object(py::str(spec.python_type)) : py::object(py::none());
  py::list choices;
  std::visit([&](auto field) {
    using F = decltype(field);
    if constexpr (std::is_same_v<F, std::monostate>) {
      d["kind"] = "python";
      d["default"] = py::none();
      d["core_default"] = py::none();
    } else {
      using T = std::decay_t<decltype(defaults.*field)>;
      d["kind"] = std::is_same_v<T, double> ? "real"
                  : std::is_same_v<T, int>    ? "integer"
                  : std::is_same_v<T, bool>   ? "boolean"
                  : std::is_enum_v<T>         ? "choice"
                                              : "diagonal";
      d["default"] = python_value(defaults.*field);
      d["core_default"] = python_value(defaults.*field);
      if constexpr (std::is_enum_v<T>)
        for (T v : nrmicp::enum_values(T{})) choices.append(nrmicp::to_string(v));
    }
  }, spec.field);
  if (spec.python_default) d["default"] = py::module_::import("ast").attr("literal_eval")(spec.python_default);
  d["choices"] = py::tuple(choices);
  const nrmicp::Range& r = spec.range;
  d["low"] = r.low;
  d["high"] = r.high;
  d["low_open"] = r.low_open;
  d["high_open"] = r.high_open;
  d["finite"] = r.finite;
  d["note"] = r.note ? py::object(py::str(r.note)) : py::object(py::none());
  py::list takes;  // the members that take it on a distributed engine (detail::distributed_takes)
  for (nrmicp::Method method : nrmicp::all_methods)
    if (nrmicp::detail::distributed_takes(spec, method)) takes.append(nrmicp::to_string(method));
  d["distributed"] = py::tuple(takes);
  d["distributed_why"] = spec.distributed_why ? py::object(py::str(spec.distributed_why)) : py::object(py::none());
  return d;
}

// The options' fields, each bound under its row's name: the per-solve ones on SolveOptions.
void bind_options(py::module_& m) {
  py::class_<SolveOptions> solve_options(m, "SolveOptions");
  solve_options.def(py::init<>());
  py::class_<Options, SolveOptions> options(m, "Options");
  options.def(py::init<>())
      .def("target", &Options::target, py::arg("res0"))
      .def("check", &Options::check, py::arg("n"), py::arg("serial_engine") = true);
  for (const nrmicp::OptionSpec& spec : nrmicp::option_table)
    std::visit([&](auto field) {
      using F = decltype(field);
      if constexpr (!std::is_same_v<F, std::monostate>) {
        using T = std::decay_t<decltype(std::declval<Options&>().*field)>;
        if (spec.scope == nrmicp::Scope::Solve)
          solve_options.def_readwrite(spec.name, static_cast<T SolveOptions::*>(field));
        else
          options.def_readwrite(spec.name, field);
      }
    }, spec.field);
  m.def("option_table", [] {
    py::list rows;
    for (const nrmicp::OptionSpec& spec : nrmicp::option_table) rows.append(option_row(spec));
    return rows;
  }, "Every option of nrmicp.solve and nrmicp::Options, one dict per row of the C++ option table (options.hpp).");
}

// Input checks and what this build has.
void bind_utilities(py::module_& m) {
  m.def("check_compressed", [](const py::array& indptr, const py::array& indices, py::ssize_t n_data,
                                py::ssize_t outer, py::ssize_t inner, const std::string& name) {
    return has_dtype<std::int64_t>(indices) ? check_compressed<std::int64_t>(indptr, indices, n_data, outer, inner, name)
                                            : check_compressed<std::int32_t>(indptr, indices, n_data, outer, inner, name);
  }, py::arg("indptr"), py::arg("indices"), py::arg("n_data"), py::arg("outer"), py::arg("inner"), py::arg("name"));
  // The amg set-up's interpolation sweeps (python/nrmicp/_hierarchy.py, _relax_interpolation).
  m.def("relax_interpolation", [](const py::array& b_indptr, const py::array& b_indices, const py::array& b_data,
                                  const py::array& is_c, const py::array& p_indptr, const py::array& p_indices,
                                  const py::array& p_data, py::ssize_t n_coarse, int sweeps, double truncate) {
    const py::ssize_t n = is_c.ndim() == 1 ? is_c.shape(0) : -1;
    if (n < 0 || b_indptr.ndim() != 1 || b_indptr.shape(0) != n + 1 || p_indptr.ndim() != 1 || p_indptr.shape(0) != n + 1)
      throw py::value_error("relax_interpolation: B (n x n), P (n rows) and is_c (n flags) must agree in n");
    if (sweeps < 0 || !(truncate >= 0 && truncate <= 1)) throw py::value_error("relax_interpolation: sweeps >= 0, 0 <= truncate <= 1");
    if (has_dtype<std::int64_t>(b_indices) != has_dtype<std::int64_t>(p_indices))
      throw py::value_error("relax_interpolation: B's and P's indices must have the same dtype");
    const auto* flags = reinterpret_cast<const unsigned char*>(checked_data<bool>(is_c, "is_c"));  // (bytes: any nonzero is C)
    std::vector<char> c(static_cast<std::size_t>(n));
    for (py::ssize_t i = 0; i < n; ++i) c[i] = flags[i] != 0;
    if (std::count(c.begin(), c.end(), char(1)) != n_coarse)  // C point k writes P's column k
      throw py::value_error("relax_interpolation: is_c must flag exactly n_coarse points (one per column of P)");
    auto run = [&](auto index) -> py::tuple {
      using I = decltype(index);
      check_compressed<I>(b_indptr, b_indices, b_data.shape(0), n, n, "B");
      check_compressed<I>(p_indptr, p_indices, p_data.shape(0), n, n_coarse, "P");
      const I* bp = checked_data<I>(b_indptr, "b_indptr");
      const CsrMap<I> B(n, n, bp[n], bp, checked_data<I>(b_indices, "b_indices"), checked_data<double>(b_data, "b_data"));
      const I* pp = checked_data<I>(p_indptr, "p_indptr");
      const I* pi = checked_data<I>(p_indices, "p_indices");
      const double* pv = checked_data<double>(p_data, "p_data");
      nrmicp::detail::CsrArrays<I> P;
      P.indptr.assign(pp, pp + n + 1);
      P.indices.assign(pi, pi + pp[n]);
      P.data.assign(pv, pv + pp[n]);
      nrmicp::detail::CsrArrays<I> out;
      {
        py::gil_scoped_release release;
        out = nrmicp::detail::relax_interpolation<I>(B, c, std::move(P), static_cast<I>(n_coarse), sweeps, truncate);
      }
      return py::make_tuple(py::array_t<I>(out.indptr.size(), out.indptr.data()),
                            py::array_t<I>(out.indices.size(), out.indices.data()),
                            py::array_t<double>(out.data.size(), out.data.data()));
    };
    return has_dtype<std::int64_t>(b_indices) ? run(std::int64_t{}) : run(std::int32_t{});
  }, py::arg("b_indptr"), py::arg("b_indices"), py::arg("b_data"), py::arg("is_c"), py::arg("p_indptr"),
     py::arg("p_indices"), py::arg("p_data"), py::arg("n_coarse"), py::arg("sweeps"), py::arg("truncate"),
     "Jacobi sweeps on the F rows of P towards B-harmonic interpolation, each row truncated; (indptr, indices, data).");
  m.def("backends", [] {
    py::dict d;
    d["cholmod"] = nrmicp::have_cholmod();
    d["umfpack"] = nrmicp::have_umfpack();
    d["eigen_llt"] = true;
    d["eigen_lu"] = true;
    return d;
  });
}

// The Python layer's rounding level of Res (its floor rule; detail::rounding_level, the core's own).
void bind_measures(py::module_& m) {
  m.def("rounding_level", [](const py::array& indptr, const py::array& indices, const py::array& data, const py::array& z,
                             const py::array& q, const py::array& g, const py::array& w, const py::object& upper,
                             const py::object& rows, const py::object& cols) {
    const py::ssize_t n = z.ndim() == 1 ? z.shape(0) : -1;
    const auto vector = [n](const py::object& v, const char* what) {
      const Eigen::VectorXd out = v.is_none() ? Eigen::VectorXd() : to_vector(v.cast<py::array>(), what);
      if (!v.is_none() && out.size() != n) throw py::value_error(std::string("rounding_level: ") + what + " must have n entries");
      return out;
    };
    const Eigen::VectorXd zv = vector(z, "z"), qv = vector(q, "q"), gv = vector(g, "g"), wv = vector(w, "w");
    const Eigen::VectorXd u = vector(upper, "upper"), r = vector(rows, "rows"), c = vector(cols, "cols");
    auto run = [&](auto index) {
      using I = decltype(index);
      check_compressed<I>(indptr, indices, data.shape(0), n, n, "A");
      const I* ap = checked_data<I>(indptr, "indptr");
      const CsrMap<I> A(n, n, ap[n], ap, checked_data<I>(indices, "indices"), checked_data<double>(data, "data"));
      return nrmicp::detail::rounding_level(A, nrmicp::detail::comm_of(A), zv, qv, gv, wv, u, r, c);
    };
    return has_dtype<std::int64_t>(indices) ? run(std::int64_t{}) : run(std::int32_t{});
  }, py::arg("indptr"), py::arg("indices"), py::arg("data"), py::arg("z"), py::arg("q"), py::arg("g"), py::arg("w"),
     py::arg("upper"), py::arg("rows"), py::arg("cols"),
     "eps ||t||_2 of Res's rounding at z (detail::rounding_level): w's terms times rows, z's over cols.");
}

}  // namespace

PYBIND11_MODULE(_core, m) {
  m.doc() = "nrmicp C++ core (internal: use the nrmicp package)";
  bind_exceptions();
  bind_vocabulary(m);
  bind_newton_stats(m);
  bind_options(m);
  bind_solver<std::int32_t>(m, "SolverI32");
  bind_solver<std::int64_t>(m, "SolverI64");
  bind_newton<std::int32_t>(m, "NewtonI32");
  bind_newton<std::int64_t>(m, "NewtonI64");
  bind_utilities(m);
  bind_measures(m);
}
