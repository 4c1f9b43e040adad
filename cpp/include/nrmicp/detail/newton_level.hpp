// nrmicp — one level of the Newton member: its matrix, the active-set test, the reduced
// systems and the fallback member (docs/SPEC.md, "The Newton member").
#pragma once

#include "../options.hpp"
#include "../result.hpp"
#include "../solver.hpp"
#include "../zeta.hpp"
#include "active_set.hpp"
#include "box.hpp"
#include "residual.hpp"
#include "timer.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <vector>

namespace nrmicp::detail {

/// `sweeps` symmetric projected Gauss–Seidel sweeps on ICP(q, A, ζ) from y: y_i ←
/// max(lower(i, y), −(q_i + Σ_{j≠i} a_ij y_j) / a_ii), the rows in order, then in reverse; rows with
/// a_ii ≤ 0 are left. lower(i, y) = ζ_i(y) with y as it stands (0 for an LCP). A: row-major (a
/// matrix or a Map); y: a vector or a Map (updated in place).
/// `upper` (optional): y_i ≤ upper(i) too (a Box's).
template <typename RowMajorMatrix, typename Q, typename Y, typename Lower>
void projected_gauss_seidel(const RowMajorMatrix& A, const Q& q, Y& y, int sweeps, Lower lower,
                            const Box* upper = nullptr) {
  static_assert(RowMajorMatrix::IsRowMajor, "projected_gauss_seidel reads rows");
  auto relax = [&](Eigen::Index i) {
    double s = q[i], d = 0;
    for (typename RowMajorMatrix::InnerIterator it(A, i); it; ++it)
      if (it.index() == i) d = it.value(); else s += it.value() * y[it.index()];
    if (d > 0) y[i] = upper ? std::min(upper->upper(i), std::max(lower(i, y), -s / d)) : std::max(lower(i, y), -s / d);
  };
  for (int k = 0; k < sweeps; ++k) {
    for (Eigen::Index i = 0; i < A.rows(); ++i) relax(i);
    for (Eigen::Index i = A.rows(); i-- > 0;) relax(i);
  }
}

/// The sweeps on LCP(q, A): y kept ≥ 0; with a (nonempty) box, lo ≤ y ≤ hi.
template <typename RowMajorMatrix, typename Q, typename Y>
void projected_gauss_seidel(const RowMajorMatrix& A, const Q& q, Y& y, int sweeps, const Box* box = nullptr) {
  if (box && !box->empty())
    projected_gauss_seidel(A, q, y, sweeps, [box](Eigen::Index i, const Y&) { return box->lower(i); }, box);
  else
    projected_gauss_seidel(A, q, y, sweeps, [](Eigen::Index, const Y&) { return 0.0; });
}

/// One level: its matrix, the weights Ω1/Ω2 of the active-set test, the reduced LCP system
/// (analysed on first use, then only refactorized) and the fallback member (nrm, Ω2 as Newton's).
template <typename MatrixType>
class NewtonLevel {
 public:
  using StorageIndex = typename MatrixType::StorageIndex;
  using Vector = Eigen::VectorXd;
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  using System = ActiveSetSystem<StorageIndex>;

  /// `options` gives Ω1, Ω2 (empty: I and diag(A)) and the inner solver.
  NewtonLevel(const MatrixType& A, const Options& options) : A_(A), options_(options) {
    options_.method = Method::Newton;
    const Parameters p = resolve_parameters(A, options_);  // Ω2: diag(A), or the row maximum where a_ii ≤ 0
    ratio_ = p.omega1.cwiseQuotient(p.omega2);
  }

  /// The levels below this one (level[0]: the next coarser one), for the multigrid-preconditioned
  /// Krylov inner solve; they must outlive this level.
  /// `borrow`: this level's LCP system frees their operators A_l while it solves (the finest
  /// level's; restore_hierarchy forms them again before the coarse levels or another system need them).
  void use_hierarchy(Hierarchy<StorageIndex> below, bool borrow = false) {
    below_ = below;
    borrow_ = borrow;
  }

  const MatrixType& matrix() const { return A_; }
  Eigen::Index size() const { return A_.rows(); }

  /// Where this level's work is timed (a solve's Result::timings, set by NewtonRun for its
  /// duration; nullptr: a scratch record nobody reads).
  void record_into(Timings* tm) { tm_ = tm; }
  Timings& timings() const { return tm_ ? *tm_ : unrecorded_; }

  /// The reduced system of the (shifted) LCP, analysed once (its pattern and analysis: setup).
  System& lcp_system() {
    if (!lcp_system_) {
      ScopedTimer t(timings().setup);
      lcp_system_ = std::make_unique<System>(A_, nullptr, options_.inner, below_, borrow_);
    }
    return *lcp_system_;
  }
  /// The hierarchy's operators, freed by the LCP system's V-cycle, formed again (setup).
  void restore_hierarchy() {
    if (!lcp_system_) return;
    ScopedTimer t(timings().setup);
    lcp_system_->restore_hierarchy();
  }
  /// Frees what a solve on this level built (the reduced system, the fallback's factorization).
  /// Nested iteration releases each coarse level once its solution is prolongated: the finer
  /// levels' solves then run without them in memory, and the next solve rebuilds them (docs/MEASUREMENTS.md).
  void release() {
    restore_hierarchy();
    lcp_system_.reset();
    fallback_.reset();
  }
  /// A system of the affine ICP (ζ = Bz + c), its V-cycle on copies of the hierarchy's operators;
  /// its time goes to `phase` (setup for a fixed ζ, factorization for a step's linearization).
  std::unique_ptr<System> affine_system(const RowMatrix& B, double Timings::*phase) {
    restore_hierarchy();
    ScopedTimer t(timings().*phase);
    return std::make_unique<System>(A_, &B, options_.inner, below_);
  }
  const char* inner_name() const { return lcp_system_ ? lcp_system_->inner_name() : "none"; }

  /// Res of z; w = Az + q and g = z − ζ(z) (ζ = Bz + c; when B is null ζ = 0, g = z is not written).
  double evaluate(const Vector& z, const Vector& q, const RowMatrix* B, const Vector* c, Vector& w, Vector& g) const {
    ScopedTimer t(timings().spmv);  // the products with A and B
    w.noalias() = A_ * z;
    w += q;
    if (!B) return residual_of(w, z);
    g.noalias() = -(*B * z);
    g += z - *c;
    return residual_of(w, g);
  }

  /// Res of the box problem (detail/box.hpp) at y; w = Ay + q.
  double evaluate(const Vector& y, const Vector& q, const Box& box, Vector& w) const {
    ScopedTimer t(timings().spmv);
    w.noalias() = A_ * y;
    w += q;
    return box.residual(w, y);
  }

  /// Res of the ICP at v (ζ(v) in zv, Av + q in wv) for any ζ: NaN only when ζ failed; +inf for
  /// a runaway v (non-finite, never handed to ζ) or an Av + q that overflowed.
  /// With the upper bound `upper` (empty: none), the bounded Res (bounded_residual).
  double icp_residual(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector& v, Vector& zv,
                      Vector& wv, const Vector& upper = Vector()) const {
    constexpr double inf = std::numeric_limits<double>::infinity();
    if (!v.allFinite()) return inf;
    if (!eval_zeta(zeta, v, zv)) return std::numeric_limits<double>::quiet_NaN();
    ScopedTimer t(timings().spmv);
    wv.noalias() = A_ * v;
    wv += q;
    const double r = bounded_residual(wv, v - zv, v, upper);
    return std::isnan(r) ? inf : r;
  }

  /// Res of the ICP at v with ζ(v) = zv given: ‖min(Av + q, v − zv)‖.
  double icp_residual_with(const Vector& q, const Vector& v, const Vector& zv) const {
    ScopedTimer t(timings().spmv);
    Vector w = q;
    w.noalias() += A_ * v;
    return residual_of(w, v - zv);
  }

  /// The rounding level of Res at z: ε (‖|A||z| + |q|‖₂ + ‖|z| + |ζ(z)|‖₂), the size of the rounding
  /// error in w = Az + q and g = z − ζ(z) (ζ(z) = z − g), below which no step brings Res.
  double rounding_level(const Vector& z, const Vector& q, const Vector& g) const {
    ScopedTimer timer(timings().spmv);
    Vector t = q.cwiseAbs();
    t.noalias() += A_.cwiseAbs() * z.cwiseAbs();
    constexpr double eps = std::numeric_limits<double>::epsilon();
    return eps * (stable_norm(t) + stable_norm(z.cwiseAbs() + (z - g).cwiseAbs()));
  }

  /// x ← Ω1 (g/Ω1 − w/Ω2) = g − (Ω1/Ω2) w, the modulus vector up to the factor γ/(2Ω1), in place
  /// (a second n-vector for the old x cost 8 MB a million unknowns); returns ‖Δx‖∞, ∞ when x was empty.
  double modulus(const Vector& w, const Vector& g, Vector& x) const {
    if (x.size() != w.size()) {
      x = g - ratio_.cwiseProduct(w);
      return std::numeric_limits<double>::infinity();
    }
    double step = 0;
    for (Eigen::Index i = 0; i < x.size(); ++i) {
      const double xi = g[i] - ratio_[i] * w[i];
      const double d = std::abs(xi - x[i]);
      if (d > step || std::isnan(d)) step = d;  // a NaN stays (as in lpNorm)
      x[i] = xi;
    }
    return step;
  }

  /// The inactive set ℐ = {x ≥ 0} = {g/Ω1 − w/Ω2 ≥ 0}. A tie x = 0 (z = ζ and w = 0) counts as
  /// inactive: if it is in fact active the solve puts it back at no cost, while holding every
  /// tie at the obstacle peels a region of exact zeros one node per step. Measured on the
  /// American put (n_space = 1600, warm start x0 = the previous time step, hierarchy None, where
  /// the far field is z = ψ, w = 0 exactly): 9.09 steps per time step with ties active, 1.49
  /// with ties inactive (the same as a plain scipy active-set loop with this rule).
  /// With a (nonempty) box, g = y and each row has one of three states (Box::state).
  void active_set(const Vector& w, const Vector& g, std::vector<char>& inactive, const Box* box = nullptr) const {
    inactive.resize(static_cast<std::size_t>(w.size()));
    for (Eigen::Index i = 0; i < w.size(); ++i) inactive[i] = state(w, g, i, box);
  }
  /// Whether (w, g)'s active set is `inactive`, without storing it.
  bool has_active_set(const Vector& w, const Vector& g, const std::vector<char>& inactive, const Box* box = nullptr) const {
    for (Eigen::Index i = 0; i < w.size(); ++i)
      if (inactive[i] != state(w, g, i, box)) return false;
    return true;
  }
  /// The number of active points of (w, g) (the complement of active_set's), without storing the set.
  std::size_t active_count(const Vector& w, const Vector& g, const Box* box = nullptr) const {
    std::size_t k = 0;
    for (Eigen::Index i = 0; i < w.size(); ++i) k += !inactive_state(state(w, g, i, box));
    return k;
  }

  /// `sweeps` symmetric projected Gauss–Seidel sweeps on LCP(q, A) from y (the free function of
  /// that name); a column-major A (no row access) is not swept at all.
  void projected_gauss_seidel(const Vector& q, Vector& y, int sweeps, const Box* box = nullptr) const {
    ScopedTimer t(timings().spmv);  // a sweep is a product with A (as the AOR types' one-pass sweep)
    if constexpr (MatrixType::IsRowMajor) detail::projected_gauss_seidel(A_, q, y, sweeps, box);
  }
  /// The same on ICP(q, A, ζ) with ζ(z) = Bz + c, from z: z_i ≥ (Bz)_i + c_i.
  void projected_gauss_seidel(const Vector& q, const RowMatrix& B, const Vector& c, Vector& z, int sweeps) const {
    ScopedTimer t(timings().spmv);
    if constexpr (MatrixType::IsRowMajor)
      detail::projected_gauss_seidel(A_, q, z, sweeps, [&](Eigen::Index i, const Vector& v) {
        double bz = c[i];
        for (typename RowMatrix::InnerIterator it(B, i); it; ++it) bz += it.value() * v[it.index()];
        return bz;
      });
  }

  /// Up to `sweeps` sweeps of the fallback member (nrm) from z0 for ICP(q, A, ζ); the best iterate.
  /// A fallback whose Ω2 + AΩ1 is singular sweeps nothing: Res +inf and the reason in the message.
  Result sweep(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector& z0, int sweeps, double tol) {
    if (!fallback_) try {
      ScopedTimer t(timings().factorization);
      fallback_.emplace(A_, fallback_options());  // factorizes Ω2 + AΩ1 once
    } catch (const FactorizationError& e) {
      if (e.reason() != FactorizationError::Reason::Singular) throw;
      Result none;
      none.z = z0;
      none.residual = std::numeric_limits<double>::infinity();
      none.status = Status::Stagnated;
      none.message = std::string("its fallback member nrm cannot be set up: ") + e.what();
      return none;
    }
    SolveOptions it = fallback_->options();
    it.tol = tol > 0 ? tol : std::numeric_limits<double>::min();
    it.maxiter = sweeps;
    it.stall_iterations = std::max(1, sweeps);
    Result r = fallback_->solve(q, zeta, &z0, {}, {}, &it);
    absorb(r.timings);
    return r;
  }
  /// ζ(v) into zv, timed; false when ζ failed.
  bool eval_zeta(const Zeta<StorageIndex>& zeta, const Vector& v, Vector& zv) const {
    ScopedTimer t(timings().zeta);
    return zeta.eval(v, zv);
  }
  Result sweep(const Vector& q, const RowMatrix* B, const Vector* c, const Vector& z0, int sweeps, double tol) {
    using Z = Zeta<StorageIndex>;
    return sweep(q, B ? Z::affine(*B, *c) : Z::none(), z0, sweeps, tol);
  }
  /// The fallback on a box problem (y ∈ [lo, hi]): the fallback member's box form (detail/modulus.hpp).
  Result sweep(const Vector& q, const Box& box, const Vector& y0, int sweeps, double tol) {
    using Z = Zeta<StorageIndex>;
    const Z lower = box.lo.size() ? Z::constant(box.lo) : Z::none();
    return sweep(q, box.hi.size() ? lower.with_upper(box.hi) : lower, y0, sweeps, tol);
  }

 private:
  char state(const Vector& w, const Vector& g, Eigen::Index i, const Box* box) const {
    if (box) return box->state(g[i], w[i], ratio_[i], i);
    return (g[i] - ratio_[i] * w[i]) >= 0 ? kInactive : kAtLower;
  }
  /// The fallback's sweeps' phases into this level's record (its set-up, a lazy factorization, as factorization).
  void absorb(const Timings& f) const {
    timings().factorization += f.factorization;
    timings().zeta += f.zeta;
    timings().spmv += f.spmv;
    timings().inner_solve += f.inner_solve;
  }

  const MatrixType& A_;
  Vector ratio_;  // Ω1/Ω2: x ≥ 0 ⇔ g − (Ω1/Ω2) w ≥ 0
  Options options_;  // the level's inner solver, Ω1, Ω2 as given (resolved when needed, not held as n-vectors)

  /// The fallback member nrm with this level's Ω1, Ω2 (built on a level's first fallback: most
  /// solves never fall back).
  Options fallback_options() const {
    const Parameters p = resolve_parameters(A_, options_);
    Options f;
    f.method = Method::NRM;
    f.omega1 = p.omega1;
    f.omega2 = p.omega2;
    f.inner = direct_inner(options_.inner);  // nrm factorizes
    f.accelerate = Accelerate::Anderson;  // plain nrm diverged on zero-diagonal LCPs (SPEC)
    return f;
  }
  std::unique_ptr<System> lcp_system_;
  Hierarchy<StorageIndex> below_;
  bool borrow_ = false;
  std::optional<Solver<MatrixType>> fallback_;
  Timings* tm_ = nullptr;
  mutable Timings unrecorded_;
};

}  // namespace nrmicp::detail
