// nrmicp — the Newton step's policy for a callable ζ with its Jacobian (NewtonStep's linearization;
// detail/newton_step.hpp): semismooth Newton on the whole ICP, linearized at each step's z. A sparse
// ∂ζ(z) gives the step's sparse system (detail/active_set.hpp), a matrix-free one its Krylov solve
// (detail/matrix_free.hpp). NewtonRun::solve_semismooth gives it its outer steps: the active set of a
// step (predict), the outer step after it (project) and the fallback (docs/SPEC.md, the Newton member).
#pragma once

#include "../result.hpp"
#include "../zeta.hpp"
#include "active_set.hpp"
#include "box.hpp"
#include "engine.hpp"
#include "matrix_free.hpp"
#include "newton_level.hpp"
#include "residual.hpp"
#include "timer.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <stdexcept>
#include <vector>

namespace nrmicp::detail {

/// A callable ζ with its Jacobian, linearized at each step's z (NewtonStep's policy): a sparse
/// ∂ζ(z) = B gives the affine step of ζ(z) + B(v − z) on the union pattern of A, I and B (a new
/// ActiveSetSystem each step: semismooth Newton on the whole ICP); a matrix-free one the same step
/// by MatrixFreeSystem. The form is the Jacobian's, per call (Zeta::Derivative).
template <typename MatrixType>
struct SemismoothLinearization {
  using Level = NewtonLevel<MatrixType>;
  using Vector = Eigen::VectorXd;
  using StorageIndex = typename MatrixType::StorageIndex;
  using Sparse = typename Engine<MatrixType>::System;
  static constexpr bool set_fixes_step = false;
  /// Its smoothing is an outer step, a whole obstacle solve: not taken after a step that met tol.
  static constexpr bool smoothing_solves = true;

  /// The reduced system of this step, of either form (the interface NewtonStep uses): a sparse ∂ζ(z)
  /// its own system on the union pattern, or (diagonal) the level's LCP system; or matrix-free.
  struct System {
    std::unique_ptr<Sparse> sparse;
    Sparse* lcp = nullptr;  ///< the level's LCP system, for a diagonal ∂ζ(z) (sparse then empty)
    MatrixFreeSystem<MatrixType> matrix_free;
    bool is_matrix_free = false;
    Sparse& assembled() { return sparse ? *sparse : *lcp; }
    bool factorize(const std::vector<char>& inactive) {
      return is_matrix_free ? matrix_free.factorize(inactive) : assembled().factorize(inactive);
    }
    int solve(const Vector& b, Vector& z, double target) {
      return is_matrix_free ? matrix_free.solve(b, z, target) : assembled().solve(b, z, target);
    }
    bool iterative() { return is_matrix_free || assembled().iterative(); }
  };

  /// `record`: where the linearizations record (outlives this).
  SemismoothLinearization(Level& level, const Vector& q, const Zeta<StorageIndex>& zeta, SemismoothRecord& record)
      : level(level), q(q), zeta(zeta), record(record), K{nullptr, nullptr, MatrixFreeSystem<MatrixType>(level, record)} {}

  Level& level;
  const Vector& q;
  const Zeta<StorageIndex>& zeta;
  SemismoothRecord& record;
  typename Zeta<StorageIndex>::Derivative J;
  Vector c;        ///< the active rows' right-hand side: ζ(z) − Jz (sparse, for z⁺), ζ(z) − z = −g (matrix-free, for d)
  Vector minus_w;  ///< matrix-free: the inactive rows' right-hand side −w = −(Az + q)
  System K;
  const Box* box = nullptr;  // (no bounds on this path)
  Vector z_last, move;       ///< the last linearization's z, and the move to it from the one before

  bool g_is_z() const { return false; }
  /// Res of the ICP at v; Av + q in w, v − ζ(v) in g, ζ(v) in zv. NaN when ζ failed. v and ζ(v) are
  /// kept while outer steps are taken (the one after a step starts from ψ = ζ(z⁺): one call of ζ less).
  double evaluate(const Vector& v, Vector& w, Vector& g, Vector& zv) const {
    const double r = level.icp_residual(q, zeta, v, zv, w);
    if (!std::isnan(r)) g = v - zv;
    if (project && !std::isnan(r)) { evaluated = v; evaluated_zeta = zv; }
    return r;
  }
  /// ∂ζ(z) and the step's system for it; false when the Jacobian failed. The Jacobian counts as ζ's
  /// time; a sparse system's analysis as this step's factorization. Every process takes the same branch.
  bool linearize(const Vector& z, const Vector& zeta_z) {
    const Comm& comm = level.comm();  // (a process whose rows stood still still takes the move)
    if (comm.all(z_last.size() == z.size()) && !comm.all(z_last == z)) move = z - z_last;
    z_last = z;
    {
      ScopedTimer t(level.timings().zeta);
      if (!comm.all(zeta.derivative(z, J))) return false;
    }
    K.is_matrix_free = J.matrix_free();
    if (comm.any(K.is_matrix_free) && !comm.all(K.is_matrix_free))
      throw std::invalid_argument("zeta_jacobian returned a linear operator on some processes and a matrix on others");
    if (!K.is_matrix_free && !assembled(z, zeta_z)) {  // an engine without J's system: its product, matrix-free
      J.product = [M = J.matrix](const double* v, double* out, Eigen::Index n) {
        Eigen::Map<Vector>(out, n).noalias() = M * Eigen::Map<const Vector>(v, n);
        return true;
      };
      K.is_matrix_free = true;
    }
    if (!K.is_matrix_free) return true;
    level.apply(z, minus_w);
    minus_w = -(minus_w + q);
    c = zeta_z - z;  // −g
    K.matrix_free.linearize(std::move(J.product), comm.stable_norm(minus_w.cwiseMax(c)));  // Res = ‖min(w, g)‖ = ‖max(−w, −g)‖
    K.sparse.reset();
    return true;
  }
  /// A sparse ∂ζ(z)'s system: the level's LCP system for a diagonal one (decoupled), else, on an engine
  /// that has it (the serial one), the union pattern's; false on an engine without it (this process's
  /// rows of J then act by their product: the rank's block, which is all of a row-local ζ's ∂ζ).
  bool assembled(const Vector& z, const Vector& zeta_z) {
    c = zeta_z - J.matrix * z;
    K.lcp = nullptr;
    K.sparse.reset();
    if (level.comm().all(decoupled())) {
      K.lcp = &level.lcp_system();
      return true;
    }
    if constexpr (Engine<MatrixType>::serial) {
      K.sparse = level.affine_system(J.matrix, &Timings::factorization, true);
      return true;
    }
    return false;
  }
  /// A diagonal ∂ζ(z) = diag(d) with d ≠ 1 (a local ζ, ζ(z)_i = f_i(z_i)): an active row of the step
  /// fixes z⁺_i = c_i / (1 − d_i) alone, so the step is the LCP's on that bound (c becomes it), on the
  /// level's LCP system: analysed once, symmetric where A is (CG on the hierarchy), where the union
  /// pattern's system is built each step and nonsymmetric (BiCGSTAB; docs/MEASUREMENTS.md, "A diagonal ζ′").
  /// (Each process tests its rows; a process whose rows are diagonal divides c all the same, which is
  /// harmless: c is used only when every process's are.)
  bool decoupled() {
    const auto& B = J.matrix;
    for (Eigen::Index i = 0; i < B.outerSize(); ++i)
      for (typename Zeta<StorageIndex>::RowMatrix::InnerIterator it(B, i); it; ++it)
        if (it.index() != i || it.value() == 1.0) return false;
    const Vector d = B.diagonal();
    c = c.cwiseQuotient((1.0 - d.array()).matrix());
    return true;
  }
  System& system() { return K; }

  /// How far J = ∂ζ(z) (the last linearization, at z) misses ζ's difference quotient along the loop's
  /// last move d, (ζ(z + εd) − ζ(z))/ε with εd 10⁻⁴ of z's size: ‖quotient − Jd‖ / max(‖quotient‖, ‖Jd‖);
  /// 0 when both vanish, NaN when ζ or the product failed. A relative step of 10⁻⁴: rounding (a float32
  /// ζ's included) and curvature are far below kJacobianMiss there. One call of ζ and one product.
  double jacobian_miss(const Vector& z, const Vector& zeta_z) {
    const Eigen::Index n = z.size();
    const Comm& comm = level.comm();
    const Vector d = comm.all(move.size() == n) && comm.inf_norm(move) > 0 ? move : Vector::Ones(n);
    const double z_norm = comm.stable_norm(z);   // (stable: squares of z's size may leave float's range)
    const double eps = kDifferenceStep * (z_norm > 0 ? z_norm : 1.0) / comm.stable_norm(d);
    Vector moved(n), jd;
    if (!level.eval_zeta(zeta, z + eps * d, moved)) return std::numeric_limits<double>::quiet_NaN();
    if (K.is_matrix_free) {
      if (!K.matrix_free.product(d, jd)) return std::numeric_limits<double>::quiet_NaN();
    } else {
      jd = J.matrix * d;
    }
    const Vector quotient = (moved - zeta_z) / eps;
    const double scale = std::max(comm.stable_norm(quotient), comm.stable_norm(jd));
    return scale > 0 ? comm.stable_norm(quotient - jd) / scale : 0.0;
  }
  static constexpr double kDifferenceStep = 1e-4;
  /// ‖z − z_before‖₂ / ‖z‖₂: how far the last linearization moved z (∞: no move known), in z's units.
  double move_ratio(const Vector& z) const {
    const Comm& comm = level.comm();
    if (!comm.all(move.size() == z.size())) return std::numeric_limits<double>::infinity();
    const double z_norm = comm.stable_norm(z);
    return z_norm > 0 ? comm.stable_norm(move) / z_norm : std::numeric_limits<double>::infinity();
  }

  /// The step's right-hand side: for z⁺ (sparse: −q on ℐ, c on 𝒜), or for the correction d = z⁺ − z
  /// (matrix-free: −w on ℐ, −g on 𝒜).
  void rhs(const std::vector<char>& set, Vector& b) const {
    for (Eigen::Index i = 0; i < b.size(); ++i)
      b[i] = inactive_state(set[i]) ? (K.is_matrix_free ? minus_w[i] : -q[i]) : c[i];
    if (K.lcp) move_bound_columns(set, b);
  }
  /// The LCP system has no active columns on the inactive rows: their part A_ℐ𝒜 z⁺_𝒜 moves to the
  /// right-hand side (as FixedLinearization::rhs does for a box's bounds).
  void move_bound_columns(const std::vector<char>& set, Vector& b) const {
    Vector t = Vector::Zero(b.size()), At(b.size());
    for (Eigen::Index i = 0; i < b.size(); ++i)
      if (!inactive_state(set[i])) t[i] = b[i];
    ScopedTimer timer(level.timings().spmv);
    multiply(level.matrix(), t, At);
    for (Eigen::Index i = 0; i < b.size(); ++i)
      if (inactive_state(set[i])) b[i] -= At[i];
  }
  /// The active set of the step from z: the one of the outer step S(ζ(z)) when `predict` is given
  /// (NewtonRun::solve_semismooth); false: the test x ≥ 0 on z decides.
  bool predict_set(const Vector& z, const Vector& zeta_z, std::vector<char>& inactive) {
    return predict && predict(z, zeta_z, inactive);
  }
  /// The fallback from z0: `fallback` when given (NewtonRun: the outer step from z0), else sweeps of
  /// the fallback member.
  Result sweep(const Vector& z0, int sweeps, double tol) {
    return fallback ? fallback(z0, sweeps, tol) : level.sweep(q, zeta, z0, sweeps, tol);
  }
  std::function<bool(const Vector&, const Vector&, std::vector<char>&)> predict;  ///< (z, ζ(z), inactive set)
  std::function<void(Vector&, const Vector&)> project;  ///< (z, ζ(z)): z ← S(ζ(z)), the outer step after a Newton step (or z kept)
  std::function<Result(const Vector&, int, double)> fallback;  ///< (z0, sweeps, tol) → the fallback's best iterate
  /// After a Newton step: the outer step from its result (`project`), kept when it lowers Res (NewtonStep::smooth).
  bool smoothable() const { return static_cast<bool>(project); }
  void smooth(Vector& z, int) const {
    if (level.comm().all(evaluated.size() == z.size() && evaluated == z)) return project(z, evaluated_zeta);
    Vector zeta_z(z.size());
    if (level.eval_zeta(zeta, z, zeta_z)) project(z, zeta_z);
  }
  mutable Vector evaluated, evaluated_zeta;  ///< the last evaluate()'s v and ζ(v) (with outer steps)
};

}  // namespace nrmicp::detail
