// nrmicp — one level of the Newton member: its matrix, the active-set test, the reduced
// systems and the fallback member (docs/SPEC.md, "The Newton member").
#pragma once

#include "../options.hpp"
#include "../result.hpp"
#include "../solver.hpp"
#include "../zeta.hpp"
#include "active_set.hpp"
#include "box.hpp"
#include "engine.hpp"
#include "residual.hpp"
#include "timer.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

namespace nrmicp::detail {

/// The fingerprint of an active set's rows from global index `offset` on (to detect cycles): a sum
/// mod 2⁶⁴ of a mix (splitmix64's finalizer) of each row not inactive, its index and whether it is at
/// its upper bound, so that processes that own parts of the set add their fingerprints.
inline std::uint64_t hash_rows(const std::vector<char>& inactive, std::uint64_t offset) {
  std::uint64_t h = 0;
  for (std::size_t i = 0; i < inactive.size(); ++i)
    if (inactive[i]) {  // inactive or at the upper bound (told apart in the lowest bit)
      std::uint64_t x = 2 * (offset + i + 1) + (inactive[i] == kAtUpper);
      x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
      x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
      h += x ^ (x >> 31);
    }
  return h;
}

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

/// The engine's sweeps (engine.hpp) of an Eigen matrix: a row-major one sweeps its rows; a
/// column-major one (no row access) is not swept.
template <typename Derived>
void sweep_rows(const Eigen::SparseMatrixBase<Derived>& A, const Eigen::VectorXd& q, Eigen::VectorXd& y, int sweeps,
                const Box* box) {
  if constexpr (Derived::IsRowMajor) projected_gauss_seidel(A.derived(), q, y, sweeps, box);
}

/// A level's active-set test, x = g − (Ω1/Ω2) w ≥ 0 row by row, and the bookkeeping of sets over
/// every process: counts, comparisons and fingerprints (to detect cycles).
template <typename MatrixType>
class ActiveSetTest {
 public:
  using Vector = Eigen::VectorXd;

  /// `ratio`: Ω1/Ω2 of the level's matrix `A` (which gives the global row indices).
  ActiveSetTest(const MatrixType& A, const Comm& comm, Vector ratio) : A_(A), comm_(comm), ratio_(std::move(ratio)) {}

  /// x ← Ω1 (g/Ω1 − w/Ω2) = g − (Ω1/Ω2) w, the modulus vector up to the factor γ/(2Ω1), in place
  /// (a second n-vector for the old x cost 8 MB a million unknowns); returns ‖Δx‖∞, ∞ when x was empty.
  double modulus(const Vector& w, const Vector& g, Vector& x) const {
    if (x.size() != w.size()) {
      x = g - ratio_.cwiseProduct(w);
      return comm_.max(std::numeric_limits<double>::infinity());  // (every process takes part)
    }
    double step = 0;
    for (Eigen::Index i = 0; i < x.size(); ++i) {
      const double xi = g[i] - ratio_[i] * w[i];
      const double d = std::abs(xi - x[i]);
      if (d > step || std::isnan(d)) step = d;  // a NaN stays (as in lpNorm)
      x[i] = xi;
    }
    return comm_.max(step);
  }

  /// The inactive set ℐ = {x ≥ 0} = {g/Ω1 − w/Ω2 ≥ 0}. A tie x = 0 (z = ζ and w = 0) counts as
  /// inactive: if it is in fact active the solve puts it back at no cost, while holding every
  /// tie at the obstacle peels a region of exact zeros one node per step (docs/MEASUREMENTS.md,
  /// "Ties in the active-set test").
  /// With a (nonempty) box, g = y and each row has one of three states (Box::state).
  void active_set(const Vector& w, const Vector& g, std::vector<char>& inactive, const Box* box = nullptr) const {
    inactive.resize(static_cast<std::size_t>(w.size()));
    for (Eigen::Index i = 0; i < w.size(); ++i) inactive[i] = state(w, g, i, box);
  }
  /// Whether (w, g)'s active set is `inactive`, without storing it.
  bool has_active_set(const Vector& w, const Vector& g, const std::vector<char>& inactive, const Box* box = nullptr) const {
    bool same = true;
    for (Eigen::Index i = 0; i < w.size() && same; ++i) same = inactive[i] == state(w, g, i, box);
    return comm_.all(same);
  }
  /// The number of active points of (w, g) (the complement of active_set's), without storing the set.
  std::size_t active_count(const Vector& w, const Vector& g, const Box* box = nullptr) const {
    std::size_t k = 0;
    for (Eigen::Index i = 0; i < w.size(); ++i) k += !inactive_state(state(w, g, i, box));
    return static_cast<std::size_t>(comm_.sum(static_cast<double>(k)));
  }
  /// The number of active points of `inactive` (every process's).
  std::size_t active_count(const std::vector<char>& inactive) const {
    const auto k = static_cast<double>(inactive.size()) - std::count(inactive.begin(), inactive.end(), kInactive);
    return static_cast<std::size_t>(comm_.sum(k));
  }
  /// Whether two active sets are the same on every process.
  bool same_set(const std::vector<char>& a, const std::vector<char>& b) const { return comm_.all(a == b); }
  /// A fingerprint of an active set (to detect cycles): a sum over its rows not inactive of a
  /// mix of the global row index and the state, so that processes add their parts.
  std::uint64_t fingerprint(const std::vector<char>& inactive) const {
    return comm_.sum(hash_rows(inactive, static_cast<std::uint64_t>(row_offset(A_))));
  }

 private:
  char state(const Vector& w, const Vector& g, Eigen::Index i, const Box* box) const {
    if (box) return box->state(g[i], w[i], ratio_[i], i);
    return (g[i] - ratio_[i] * w[i]) >= 0 ? kInactive : kAtLower;
  }

  const MatrixType& A_;
  const Comm& comm_;
  Vector ratio_;  // Ω1/Ω2: x ≥ 0 ⇔ g − (Ω1/Ω2) w ≥ 0
};

/// A level's fallback member: nrm with the level's Ω1, Ω2 (Ω2 as Newton's) and Anderson, set up on
/// the level's first fallback (most solves never fall back).
template <typename MatrixType>
class FallbackMember {
 public:
  using Vector = Eigen::VectorXd;

  explicit FallbackMember(const MatrixType& A) : A_(A) {}

  /// Up to `sweeps` sweeps from z0 for ICP(q, A, ζ); the best iterate. `level`: the level's options
  /// (Ω1, Ω2, inner); the sweeps' phases go to `tm`. A fallback whose Ω2 + AΩ1 is singular sweeps
  /// nothing: Res +inf and the reason in the message.
  Result sweep(const Options& level, const Vector& q, const Zeta<typename MatrixType::StorageIndex>& zeta,
               const Vector& z0, int sweeps, double tol, Timings& tm) {
    if (!fallback_) try {
      ScopedTimer t(tm.factorization);
      fallback_.emplace(A_, options(level));  // factorizes Ω2 + AΩ1 once
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
    absorb(tm, r.timings);
    return r;
  }
  /// Frees its factorization (set up again on the next fallback).
  void reset() { fallback_.reset(); }

 private:
  /// nrm with the level's Ω1, Ω2.
  Options options(const Options& level) const {
    const Parameters p = resolve_parameters(A_, level);
    Options f;
    f.method = Method::NRM;
    f.omega1 = p.omega1;
    f.omega2 = p.omega2;
    f.inner = direct_inner(level.inner);  // nrm factorizes
    f.accelerate = Accelerate::Anderson;  // plain nrm diverged on zero-diagonal LCPs (SPEC)
    return f;
  }
  /// The sweeps' phases into the level's record (its set-up, a lazy factorization, as factorization).
  static void absorb(Timings& tm, const Timings& f) {
    tm.factorization += f.factorization;
    tm.zeta += f.zeta;
    tm.spmv += f.spmv;
    tm.inner_solve += f.inner_solve;
  }

  const MatrixType& A_;
  std::optional<typename Engine<MatrixType>::Fallback> fallback_;
};

/// rounding_level of the vectors times `s` (a power of two), over s.
template <typename MatrixType>
double scaled_rounding_level(const MatrixType& A, const Comm& comm, double s, const Eigen::VectorXd& z,
                             const Eigen::VectorXd& q, const Eigen::VectorXd& g, const Eigen::VectorXd& w,
                             const Eigen::VectorXd& upper, const Eigen::VectorXd& rows, const Eigen::VectorXd& cols) {
  Eigen::VectorXd t = s * q.cwiseAbs();
  abs_multiply_add(A, s * z.cwiseAbs(), t);
  if (rows.size()) t.array() *= rows.array();
  // the terms in z's units over the column weights: z_i, g_i and u_i times s / cols_i
  const auto c = [&](Eigen::Index i) { return cols.size() ? s / cols[i] : s; };
  Eigen::VectorXd scaled_upper;
  if (upper.size() && (s != 1.0 || cols.size())) {
    scaled_upper.resize(upper.size());
    for (Eigen::Index i = 0; i < upper.size(); ++i) scaled_upper[i] = c(i) * upper[i];
  }
  const Eigen::VectorXd& u = scaled_upper.size() ? scaled_upper : upper;
  for (Eigen::Index i = 0; i < t.size(); ++i)
    t[i] = term_rounding(t[i], rows.size() ? s * w[i] * rows[i] : s * w[i], c(i) * g[i], c(i) * z[i], u, i);
  return std::numeric_limits<double>::epsilon() * comm.stable_norm(t);
}

/// ε ‖t‖₂, t_i the rounding of row i's term of Res (term_rounding): rows_i (|A||z| + |q|)_i where it is w_i
/// (its term rows_i w_i), (|z_i| + |ζ_i|) / cols_i where it is g_i / cols_i (rows, cols empty: ones). What double
/// precision resolves of Res at z: the Newton member's floor, and the Python layer's (one rule, both engines).
template <typename MatrixType>
double rounding_level(const MatrixType& A, const Comm& comm, const Eigen::VectorXd& z, const Eigen::VectorXd& q,
                      const Eigen::VectorXd& g, const Eigen::VectorXd& w, const Eigen::VectorXd& upper = Eigen::VectorXd(),
                      const Eigen::VectorXd& rows = Eigen::VectorXd(), const Eigen::VectorXd& cols = Eigen::VectorXd()) {
  const double level = scaled_rounding_level(A, comm, 1.0, z, q, g, w, upper, rows, cols);
  if (std::isfinite(level) || !comm.all(z.allFinite() && q.allFinite())) return level;
  // terms near float's limit overflowed (z of 1e307): the same in units of 2^600, exact but for subnormals
  constexpr double units = 0x1p600;
  return units * scaled_rounding_level(A, comm, 1.0 / units, z, q, g, w, upper, rows, cols);
}

/// One level: its matrix, the weights Ω1/Ω2 of the active-set test, the reduced LCP system
/// (analysed on first use, then only refactorized) and the fallback member (nrm, Ω2 as Newton's).
template <typename MatrixType>
class NewtonLevel {
 public:
  using StorageIndex = typename MatrixType::StorageIndex;
  using Vector = Eigen::VectorXd;
  using RowMatrix = typename Engine<MatrixType>::Coarse;
  using System = typename Engine<MatrixType>::System;

  /// `options` gives Ω1, Ω2 (empty: I and diag(A)) and the inner solver.
  NewtonLevel(const MatrixType& A, const Options& options)
      : A_(A), comm_(comm_of(A)), options_(newton_options(options)), test_(A, comm_, ratio(A, options_)) {}

  /// The levels below this one (level[0]: the next coarser one), for the multigrid-preconditioned
  /// Krylov inner solve; they must outlive this level.
  /// `borrow`: this level's LCP system frees their operators A_l while it solves (the finest
  /// level's; restore_hierarchy forms them again before the coarse levels or another system need them).
  void use_hierarchy(typename Engine<MatrixType>::Hierarchy below, bool borrow = false) {
    below_ = below;
    borrow_ = borrow;
  }

  const MatrixType& matrix() const { return A_; }
  /// The rows this process owns (every row, serially).
  Eigen::Index size() const { return A_.rows(); }
  /// The reductions over every process (detail/comm.hpp).
  const Comm& comm() const { return comm_; }
  /// out = A v, timed.
  void apply(const Vector& v, Vector& out) const {
    ScopedTimer t(timings().spmv);
    multiply(A_, v, out);
  }

  /// Where this level's work is timed (a solve's Result::timings, set by NewtonRun for its
  /// duration; nullptr: a scratch record nobody reads); a new record begins eval_zeta's memo afresh.
  void record_into(Timings* tm) {
    tm_ = tm;
    memo_ = {};
  }
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
  /// levels' solves then run without them in memory, and the next solve rebuilds them
  /// (docs/MEASUREMENTS.md, "The algebraic hierarchy on grids", Memory).
  void release() {
    restore_hierarchy();
    lcp_system_.reset();
    fallback_.reset();
  }
  /// A system of the affine ICP (ζ = Bz + c), its V-cycle on copies of the hierarchy's operators;
  /// its time goes to `phase` (setup for a fixed ζ, factorization for a step's linearization).
  /// `direct_unless_cg`: factorized unless inner = cg asks for the Krylov solve (a step's ∂ζ(z) that
  /// couples distant rows, which a V-cycle of A does not precondition: docs/MEASUREMENTS.md,
  /// "A nonlocal sparse ζ′").
  std::unique_ptr<System> affine_system(const RowMatrix& B, double Timings::*phase, bool direct_unless_cg = false) {
    restore_hierarchy();
    ScopedTimer t(timings().*phase);
    if (direct_unless_cg && options_.inner != Inner::CG) return std::make_unique<System>(A_, &B, options_.inner, decltype(below_){});
    return std::make_unique<System>(A_, &B, options_.inner, below_);
  }
  const char* inner_name() const { return lcp_system_ ? lcp_system_->inner_name() : "none"; }

  /// Res of z; w = Az + q and g = z − ζ(z) (ζ = Bz + c; when B is null ζ = 0, g = z is not written).
  double evaluate(const Vector& z, const Vector& q, const RowMatrix* B, const Vector* c, Vector& w, Vector& g) const {
    ScopedTimer t(timings().spmv);  // the products with A and B
    multiply(A_, z, w);
    w += q;
    if (!B) return comm_.stable_norm(w.cwiseMin(z));
    multiply(*B, z, g);
    g = (z - *c) - g;
    return comm_.stable_norm(w.cwiseMin(g));
  }

  /// Res of the box problem (detail/box.hpp) at y; w = Ay + q.
  double evaluate(const Vector& y, const Vector& q, const Box& box, Vector& w) const {
    ScopedTimer t(timings().spmv);
    multiply(A_, y, w);
    w += q;
    return box.residual(w, y, comm_);
  }

  /// Res of the ICP at v (ζ(v) in zv, Av + q in wv) for any ζ: NaN only when ζ failed; +inf for
  /// a runaway v (non-finite, never handed to ζ) or an Av + q that overflowed.
  /// With the upper bound `upper` (empty: none), the bounded Res (bounded_residual).
  double icp_residual(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector& v, Vector& zv,
                      Vector& wv, const Vector& upper = Vector()) const {
    constexpr double inf = std::numeric_limits<double>::infinity();
    if (!comm_.all(v.allFinite())) return inf;
    if (!comm_.all(eval_zeta(zeta, v, zv))) return std::numeric_limits<double>::quiet_NaN();
    return icp_residual_at(q, v, zv, wv, upper);
  }
  /// The same with ζ(v) = zv given (a finite v): no evaluation of ζ; without `upper`, ‖min(Av + q, v − zv)‖.
  double icp_residual_at(const Vector& q, const Vector& v, const Vector& zv, Vector& wv,
                         const Vector& upper = Vector()) const {
    ScopedTimer t(timings().spmv);
    multiply(A_, v, wv);
    wv += q;
    const double r = bounded_residual(wv, v - zv, v, upper, comm_);
    return std::isnan(r) ? std::numeric_limits<double>::infinity() : r;
  }

  /// The rounding level of Res at z: ε ‖t‖₂, t_i the rounding of the term Res takes in row i
  /// (term_rounding: |A||z| + |q| where it is w_i = (Az + q)_i, |z_i| + |ζ_i(z)| where it is
  /// g_i = z_i − ζ_i(z)), below which no step brings Res. Row by row, not the two parts' sums: a Res
  /// made of w's entries alone is not floored by z's size (docs/MEASUREMENTS.md, "The rounding level
  /// row by row"). `upper`: the bound of bounded_residual (empty: none); `rows`: weights d > 0 of
  /// Res's rows, its terms d∘w (empty: none; the default rule's Res_E).
  double rounding_level(const Vector& z, const Vector& q, const Vector& g, const Vector& w,
                        const Vector& upper = Vector(), const Vector& rows = Vector()) const {
    ScopedTimer timer(timings().spmv);
    return detail::rounding_level(A_, comm_, z, q, g, w, upper, rows);
  }
  /// The same for the box problem lo ≤ y ≤ hi (Box::residual's terms).
  double rounding_level(const Vector& y, const Vector& q, const Box& box, const Vector& w) const {
    return box.has_lo ? rounding_level(y, q, y - box.lo, w, box.hi) : rounding_level(y, q, y, w, box.hi);
  }

  /// The active-set test (Ω1/Ω2 of this level) and the bookkeeping of sets.
  const ActiveSetTest<MatrixType>& test() const { return test_; }

  /// `sweeps` symmetric projected Gauss–Seidel sweeps on LCP(q, A) from y (the free function of
  /// that name); a column-major A (no row access) is not swept at all.
  void projected_gauss_seidel(const Vector& q, Vector& y, int sweeps, const Box* box = nullptr) const {
    ScopedTimer t(timings().spmv);  // a sweep is a product with A (as the AOR types' one-pass sweep)
    sweep_rows(A_, q, y, sweeps, box);
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
    return fallback_.sweep(options_, q, zeta, z0, sweeps, tol, timings());
  }
  /// ζ(v) into zv, timed; false when ζ failed. A functor ζ asked again at the v of its last call is
  /// not called (a step's Res, its outer step, the stop rules and the next linearization all ask at
  /// one z); the memo lives for one solve (record_into) and every process hits or misses together.
  bool eval_zeta(const Zeta<StorageIndex>& zeta, const Vector& v, Vector& zv) const {
    ScopedTimer t(timings().zeta);
    if (zeta.kind() != ZetaKind::Functor) return zeta.eval(v, zv);
    if (comm_.all(memo_.z.size() == v.size() && memo_.z == v)) {
      zv = memo_.zeta;
      return true;
    }
    memo_.z = v;  // (kept before the call: zv may be v itself)
    if (!comm_.all(zeta.eval(memo_.z, zv))) {  // (failed on any process: on every one)
      memo_.z.resize(0);
      return false;
    }
    memo_.zeta = zv;
    return true;
  }
  /// u(v) of an implicit upper bound into uv, timed as ζ is; false when u failed (Zeta::eval_upper).
  bool eval_upper(const Zeta<StorageIndex>& zeta, const Vector& v, Vector& uv) const {
    ScopedTimer t(timings().zeta);
    return zeta.eval_upper(v, uv);
  }
  Result sweep(const Vector& q, const RowMatrix* B, const Vector* c, const Vector& z0, int sweeps, double tol) {
    using Z = Zeta<StorageIndex>;
    if constexpr (Engine<MatrixType>::serial) return sweep(q, B ? Z::affine(*B, *c) : Z::none(), z0, sweeps, tol);
    return sweep(q, Z::none(), z0, sweeps, tol);  // (an engine without affine ζ has no B)
  }
  /// The fallback on a box problem (y ∈ [lo, hi]): the fallback member's box form (detail/modulus.hpp).
  Result sweep(const Vector& q, const Box& box, const Vector& y0, int sweeps, double tol) {
    using Z = Zeta<StorageIndex>;
    const Z lower = box.has_lo ? Z::constant(box.lo) : Z::none();
    return sweep(q, box.has_hi ? lower.with_upper(box.hi) : lower, y0, sweeps, tol);
  }

 private:
  static Options newton_options(Options o) {
    o.method = Method::Newton;
    return o;
  }
  /// Ω1/Ω2 of the active-set test, resolved (Ω2: diag(A), or the row maximum where a_ii ≤ 0).
  static Vector ratio(const MatrixType& A, const Options& o) {
    const Parameters p = resolve_parameters(A, o);
    return p.omega1.cwiseQuotient(p.omega2);
  }
  const MatrixType& A_;
  const Comm& comm_;
  Options options_;  // the level's inner solver, Ω1, Ω2 as given (resolved when needed, not held as n-vectors)
  ActiveSetTest<MatrixType> test_;
  std::unique_ptr<System> lcp_system_;
  typename Engine<MatrixType>::Hierarchy below_;
  bool borrow_ = false;
  FallbackMember<MatrixType> fallback_{A_};
  Timings* tm_ = nullptr;
  mutable Timings unrecorded_;
  mutable struct { Vector z, zeta; } memo_;  // eval_zeta's last functor call: z and ζ(z) (empty: none)
};

}  // namespace nrmicp::detail
