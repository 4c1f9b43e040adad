// nrmicp._petsc — the Newton member and the stationary members (synchronous multisplitting, the serial
// nrmicp::Solver's one loop) on the PETSc engine (nrmicp/petsc.hpp), for nrmicp.distributed.
// Conversion only: petsc4py objects arrive as their handles (Mat pointers), vectors as this
// process's rows (numpy), and the result goes back as the core module's dict. Built when CMake finds
// PETSc and MPI; the core module (_core) does not need it. The GIL is held throughout: PETSc calls
// made with it released crashed in a test where holding it worked (docs/DISTRIBUTED.md).
#include <nrmicp/petsc.hpp>

#include "bridge.hpp"

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace py = pybind11;
using namespace nrmicp::bridge;

namespace {

using Matrix = nrmicp::petsc::Matrix;
using Core = nrmicp::Newton<Matrix>;
using Zeta = nrmicp::Zeta<PetscInt>;

Matrix from_handle(std::uintptr_t handle, const char* what) {
  if (!handle) throw py::value_error(std::string(what) + " is a destroyed (null) PETSc Mat");
  return Matrix(reinterpret_cast<Mat>(handle));
}

std::vector<Matrix> from_handles(const std::vector<std::uintptr_t>& handles, const char* what) {
  std::vector<Matrix> out;
  for (std::size_t l = 0; l < handles.size(); ++l)
    out.push_back(from_handle(handles[l], (std::string(what) + "[" + std::to_string(l) + "]").c_str()));
  return out;
}

/// ζ of this process's rows (an affine ζ comes as a callable: the engine has no B), with its Jacobian
/// (_newton.core_jacobian's: a linear operator's product or a diagonal on this process's rows) when given.
Zeta zeta_of(nrmicp::ZetaKind kind, py::object c, py::object fn, py::object jacobian = py::none()) {
  switch (kind) {
    case nrmicp::ZetaKind::None: return Zeta::none();
    case nrmicp::ZetaKind::Constant: return Zeta::constant(to_vector(c.cast<py::array>(), "zeta"));
    case nrmicp::ZetaKind::Functor:
      if (jacobian.is_none()) return Zeta::functor(CallableZeta(fn));
      return Zeta::functor(CallableZeta(fn), Zeta::Differential(CallableJacobian<PetscInt>(jacobian)));
    case nrmicp::ZetaKind::Affine: break;
  }
  throw py::value_error("zeta: an affine zeta is not available on the PETSc engine");
}

/// The progress lines of process 0 (every process runs the same loop: one set of lines).
nrmicp::detail::Progress rank0_progress(const Matrix& A, const py::object& progress) {
  MPI_Comm comm;
  int rank = 0;
  nrmicp::petsc::check(PetscObjectGetComm(reinterpret_cast<PetscObject>(A.get()), &comm), "PetscObjectGetComm");
  MPI_Comm_rank(comm, &rank);
  return rank == 0 ? make_progress(progress) : nrmicp::detail::Progress{};
}

/// The nesting hierarchy: BoomerAMG's (nrmicp/petsc/hierarchy.hpp) when `amg`, else the given prolongations.
nrmicp::petsc::AmgHierarchy hierarchy_of(const Matrix& A, const std::vector<std::uintptr_t>& prolongations, bool amg) {
  if (amg) return nrmicp::petsc::amg_hierarchy(A);
  return {from_handles(prolongations, "prolongations"), {}};
}

/// What both PETSc cores' bindings share (module.cpp's PyCore on the serial side): A, the core, its solve,
/// set-up timings and inner solver, and close(). `what` names the core in the error of a closed one.
template <typename CoreType>
class PyPetscCore {
 public:
  /// Destroys the core and lets go of A now (collective: a KSP's MUMPS factors, a Mat's last reference are
  /// freed by every process together), not when the garbage collector takes this object, which it does at
  /// a different time on each process.
  void close() {
    core_.reset();
    A_ = Matrix();
  }
  /// The serial core's solve (module.cpp's PyCore::solve) but ζ's B: an affine ζ arrives as a callable.
  py::dict solve(py::array q, nrmicp::ZetaKind kind, py::object zeta_c, py::object zeta_fn, py::object x0,
                 py::object callback, const nrmicp::SolveOptions& it, py::object zeta_jacobian, py::object progress,
                 py::object upper) {
    const Eigen::VectorXd qv = to_vector(q, "q");
    std::optional<Eigen::VectorXd> z0;
    if (!x0.is_none()) z0 = to_vector(x0.cast<py::array>(), "x0");
    const auto zeta = with_upper(zeta_of(kind, zeta_c, zeta_fn, zeta_jacobian), upper, qv.size());
    const nrmicp::Result r =
        core().solve(qv, zeta, z0 ? &*z0 : nullptr, make_callback(callback), {}, &it, rank0_progress(A_, progress));
    return result_dict(r, it.record_history);
  }
  py::dict setup_timings() const { return timings_dict(core().setup_timings()); }
  std::string inner() const { return core().inner_name(); }

 protected:
  PyPetscCore(std::uintptr_t A, const char* what) : A_(from_handle(A, "A")), what_(what) {}
  const CoreType& core() const {
    if (!core_) throw py::value_error(std::string("this PETSc ") + what_ + " was closed");
    return *core_;
  }
  CoreType& core() { return const_cast<CoreType&>(std::as_const(*this).core()); }

  Matrix A_;
  std::optional<CoreType> core_;

 private:
  const char* what_;
};

/// The Newton member over a PETSc Mat: set up once (the hierarchy, its Galerkin operators), solved
/// with this process's rows of q, ζ and x0.
class PyPetscNewton : public PyPetscCore<Core> {
 public:
  PyPetscNewton(std::uintptr_t A, const nrmicp::Options& o, const std::vector<std::uintptr_t>& prolongations, bool amg)
      : PyPetscCore(A, "Newton member") {
    nrmicp::petsc::AmgHierarchy levels = hierarchy_of(A_, prolongations, amg);
    core_.emplace(A_, o, levels.prolongations, levels.coarse_operators);  // (the core holds what it uses)
  }
  py::dict polish(py::array q, nrmicp::ZetaKind kind, py::object zeta_c, py::object zeta_fn, py::array z, double tol,
                  py::object upper) {
    const Eigen::VectorXd qv = to_vector(q, "q");
    const auto zeta = with_upper(zeta_of(kind, zeta_c, zeta_fn), upper, qv.size());
    return result_dict(core().polish(qv, zeta, to_vector(z, "z"), tol), false);
  }
  int levels() const { return core().levels(); }
  py::dict hierarchy() const {
    const nrmicp::HierarchyReport& h = core().hierarchy();
    py::dict d;
    d["requested"] = h.requested; d["used"] = h.used; d["reason"] = h.reason;
    return d;
  }
};

/// A stationary member (nrm, nrmm, nrmaor, nrmsor, nrmgs, nrmj, two_sweep) over a PETSc Mat: the
/// serial nrmicp::Solver on the PETSc engine, each process's diagonal block split (multisplitting).
class PyPetscSolver : public PyPetscCore<nrmicp::Solver<Matrix>> {
 public:
  PyPetscSolver(std::uintptr_t A, const nrmicp::Options& o) : PyPetscCore(A, "solver") { core_.emplace(A_, o); }
};

/// w = Az + q and Res(z) of ICP(q, A, ζ) (with `upper`: the bounded Res, an implicit one at z), every process's rows
/// together; with `rows` (weights d > 0), the default rule's Res_E on d∘w (w itself unweighted); with `rounding`,
/// also Res's rounding level at z (the Newton member's floor, detail::NewtonLevel::rounding_level). For the
/// distributed entry point's re-measures: its target (Res at z = 0), the paper's Res, the default rule's floor.
py::dict measure(std::uintptr_t A, py::array q, nrmicp::ZetaKind kind, py::object zeta_c, py::object zeta_fn,
                 py::object upper, py::array z, bool rounding, py::object rows) {
  const Matrix M = from_handle(A, "A");
  nrmicp::Options o;
  o.method = nrmicp::Method::Newton;
  const nrmicp::detail::NewtonLevel<Matrix> level(M, o);
  const Eigen::VectorXd qv = to_vector(q, "q"), zv = to_vector(z, "z");
  const bool weighted = !rows.is_none();  // (alike on every process: d is empty on one without rows)
  const Eigen::VectorXd d = weighted ? to_vector(rows.cast<py::array>(), "rows") : Eigen::VectorXd();
  const Zeta zeta = with_upper(zeta_of(kind, zeta_c, zeta_fn), upper, qv.size());
  Eigen::VectorXd w, zeta_z, u;
  if (!zeta.eval_upper(zv, u)) throw py::value_error("upper(z) failed (or gave NaN or -inf) at the returned z");
  py::dict d_out;
  double res = level.icp_residual(qv, zeta, zv, zeta_z, w, u);
  const Eigen::VectorXd dw = weighted ? Eigen::VectorXd(d.cwiseProduct(w)) : w;
  if (weighted && std::isfinite(res)) {   // (an infinite Res: no certificate, weighted or not)
    res = nrmicp::detail::bounded_residual(dw, zv - zeta_z, zv, u, M.comm());
    if (std::isnan(res)) res = std::numeric_limits<double>::infinity();
  }
  d_out["residual"] = res;
  d_out["w"] = py::array_t<double>(w.size(), w.data());
  if (rounding) d_out["rounding_level"] = level.rounding_level(zv, qv, zv - zeta_z, w, u, d);
  return d_out;
}

/// The 'amg' hierarchy of A (nrmicp/petsc/hierarchy.hpp), built and let go: each coarse operator's rows and
/// nonzeros, finest first (sums over every process), for the tests and the measurements.
py::dict amg_levels(std::uintptr_t A) {
  const nrmicp::petsc::AmgHierarchy h = nrmicp::petsc::amg_hierarchy(from_handle(A, "A"));
  py::list rows, nonzeros;
  for (const Matrix& C : h.coarse_operators) {
    PetscInt n;
    nrmicp::petsc::check(MatGetSize(C.get(), &n, nullptr), "MatGetSize");
    rows.append(n);
    nonzeros.append(static_cast<double>(nrmicp::petsc::global_nonzeros(C.get())));
  }
  py::dict d;
  d["rows"] = rows;
  d["nonzeros"] = nonzeros;
  return d;
}

}  // namespace

PYBIND11_MODULE(_petsc, m) {
  m.doc() = "nrmicp's Newton and stationary members on the PETSc engine (used by nrmicp.distributed)";
  py::module_::import("nrmicp._core");  // Options, SolveOptions, ZetaKind, NewtonStats: the core's types
  py::class_<PyPetscNewton>(m, "Newton")
      .def(py::init<std::uintptr_t, const nrmicp::Options&, const std::vector<std::uintptr_t>&, bool>(),
           py::arg("A"), py::arg("options"), py::arg("prolongations"), py::arg("amg") = false)
      .def("solve", &PyPetscNewton::solve, py::arg("q"), py::arg("zeta_kind"), py::arg("zeta_c"), py::arg("zeta_fn"),
           py::arg("x0"), py::arg("callback"), py::arg("options"), py::arg("zeta_jacobian") = py::none(),
           py::arg("progress") = py::none(), py::arg("upper") = py::none())
      .def("polish", &PyPetscNewton::polish, py::arg("q"), py::arg("zeta_kind"), py::arg("zeta_c"), py::arg("zeta_fn"),
           py::arg("z"), py::arg("tol"), py::arg("upper") = py::none())
      .def_property_readonly("levels", &PyPetscNewton::levels)
      .def_property_readonly("hierarchy", &PyPetscNewton::hierarchy)
      .def_property_readonly("inner", &PyPetscNewton::inner)
      .def("setup_timings", &PyPetscNewton::setup_timings)
      .def("close", &PyPetscNewton::close, "Destroys the core now, on every process together (collective).");
  py::class_<PyPetscSolver>(m, "Solver")
      .def(py::init<std::uintptr_t, const nrmicp::Options&>(), py::arg("A"), py::arg("options"))
      .def("solve", &PyPetscSolver::solve, py::arg("q"), py::arg("zeta_kind"), py::arg("zeta_c"), py::arg("zeta_fn"),
           py::arg("x0"), py::arg("callback"), py::arg("options"), py::arg("zeta_jacobian") = py::none(),
           py::arg("progress") = py::none(), py::arg("upper") = py::none())
      .def_property_readonly("inner", &PyPetscSolver::inner)
      .def("setup_timings", &PyPetscSolver::setup_timings)
      .def("close", &PyPetscSolver::close, "Destroys the core now, on every process together (collective).");
  m.attr("hierarchy_strong_threshold") = nrmicp::petsc::kStrongThreshold;  // (the rule's, for its tests)
  m.def("amg_levels", &amg_levels, py::arg("A"),
        "{'rows', 'nonzeros'} of the 'amg' hierarchy's coarse operators, finest first (built and let go).");
  m.def("check_layout", [](std::uintptr_t A) { nrmicp::petsc::check_layout(from_handle(A, "A")); }, py::arg("A"),
        "ValueError unless A is AIJ, square, its rows and columns split alike (local queries).");
  m.def("check_diagonal", [](std::uintptr_t A) { nrmicp::petsc::check_diagonal(from_handle(A, "A")); }, py::arg("A"),
        "ValueError naming this process's first row of A the PETSc engine refuses (a_ii not positive and normal); "
        "collective: after check_layout passed on every process.");
  m.def("row_max_abs", [](std::uintptr_t A) {
    const Eigen::VectorXd r = from_handle(A, "A").row_max_abs();
    return py::array_t<double>(r.size(), r.data());
  }, py::arg("A"), "max_j |a_ij| of this process's rows of A (PETSc's MatGetRowMaxAbs).");
  m.def("measure", &measure, py::arg("A"), py::arg("q"), py::arg("zeta_kind"), py::arg("zeta_c"), py::arg("zeta_fn"),
        py::arg("upper"), py::arg("z"), py::arg("rounding") = false, py::arg("rows") = py::none(),
        "{'w', 'residual'[, 'rounding_level']} of z: w = Az + q and Res(z) over every process's rows.");
}
