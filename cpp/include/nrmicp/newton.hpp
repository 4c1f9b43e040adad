// nrmicp — the Newton member: a semismooth Newton method on the modulus equation of Theorem 3.1,
//
//   F(x) = (Ω2 + AΩ1)x − (Ω2 − AΩ1)|x| + γ(Aζ + q) = 0,
//
// with nested iteration over user-supplied prolongations and a fallback to the paper's
// iteration (docs/SPEC.md, "The Newton member"). A step with D = diag(sign x) solves the piece
// of F on which x lies: with the inactive set ℐ = {x > 0} (z − ζ > 0, w = 0) and the active set
// 𝒜 = {x ≤ 0} (z − ζ = 0), i.e. x > 0 ⇔ (z − ζ)/Ω1 > w/Ω2:
//   (Az + q)_ℐ = 0,   (z − ζ(z))_𝒜 = 0            (detail/active_set.hpp)
// and x⁺ is recovered by the start formula x = γ/2 (Ω1⁻¹ g − Ω2⁻¹ w). For an LCP this is the
// primal–dual active-set method; on each piece F is affine, so the step is exact there.
//
// Globalization: a step whose Res is not below the largest Res of the last 5 iterates (a
// non-monotone test: the active-set steps are not monotone in Res — measured on the nested 2D
// obstacle, 2813 → 1.6e-3 → 1.4e-2 → 1e-13 — but the reference value never grows; the first step
// after a start is exempt: a start is not a Newton iterate), an active set seen before (a cycle),
// or a singular reduced system hands over to sweeps of nrm (M = A, the paper's first member; it
// converged on P-matrices where both nrmgs and the active-set steps cycle) from the best
// iterate (10, then 20, 40, ... sweeps), after which Newton resumes. The result says which path
// was taken. Every iterate goes to the family's stopping Monitor (detail/stopping.hpp), as in
// Method 3.1's loop; the Newton-specific ends (a settled active set, a fallback that brings
// nothing, maxiter Newton steps) are decided in newton_loop.
#pragma once

#include "detail/active_set.hpp"
#include "detail/residual.hpp"
#include "detail/sparse_product.hpp"
#include "detail/timer.hpp"
#include "options.hpp"
#include "result.hpp"
#include "solver.hpp"
#include "splitting.hpp"
#include "zeta.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <unordered_set>
#include <vector>

namespace nrmicp {

namespace detail {

/// What the Newton loop on one level needs to know and may report to.
struct NewtonControl {
  double tol = 0;             ///< Res < tol ends the solve; 0: only a settled active set does
  /// Warm start by active set: when not empty, the first step uses this inactive set instead of
  /// the one of the start (after a change of the obstacle the old contact set is a far better
  /// guess than the test on the old z: measured on thermoforming_1d, 1 step instead of 6).
  std::vector<char> start_set;
  int maxiter = 50;           ///< Newton steps
  double forcing = 0;         ///< an iterative inner solve may stop at forcing × Res (inexact Newton)
  int sweep_budget = 0;       ///< fallback sweeps allowed in all (0: no fallback)
  bool record_history = false;
  Callback callback;  ///< finest level only; called with z = y + shift
  Poll poll;
  Progress progress;  ///< finest level only: the verbose report (Options::verbose seconds apart)
  int verbose = 0;
  const Eigen::VectorXd* shift = nullptr;  ///< the constant obstacle of a shifted LCP (for the callback)
};

/// What the Newton loop on one level did.
struct NewtonOutcome {
  Eigen::VectorXd z;          ///< best iterate (smallest Res)
  double residual = std::numeric_limits<double>::infinity();
  Status status = Status::MaxIterations;
  std::string message;
  bool settled = false;       ///< the active set repeated: z solves the problem to rounding
  std::vector<char> inactive; ///< the inactive set of z's last step (empty if no step was taken)
  int steps = 0, sweeps = 0, solves = 0;
  long long inner_iterations = 0;  ///< of the iterative inner solve (inner = cg)
  std::vector<int> history_iteration;
  std::vector<double> history_seconds, history_residual;
};

/// The non-monotone acceptance test (Grippo–Lampariello–Lucidi): a new Res is acceptable when it
/// is below the largest of the last 5 accepted ones, so the reference value never grows.
class NonMonotone {
 public:
  explicit NonMonotone(double r) { reset(r); }
  void reset(double r) { recent_.assign(1, r); }
  bool acceptable(double r) const { return std::isfinite(r) && r < *std::max_element(recent_.begin(), recent_.end()); }
  void push(double r) {
    recent_.push_back(r);
    if (recent_.size() > 5) recent_.erase(recent_.begin());
  }

 private:
  std::vector<double> recent_;
};

/// FNV-1a hash of an active set (to detect cycles).
inline std::uint64_t hash_set(const std::vector<char>& inactive) {
  std::uint64_t h = 1469598103934665603ull;
  for (std::size_t i = 0; i < inactive.size(); ++i)
    if (inactive[i]) { h ^= static_cast<std::uint64_t>(i) + 1; h *= 1099511628211ull; }
  return h;
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
  NewtonLevel(const MatrixType& A, const Options& options) : A_(A), inner_(options.inner) {
    Options o = options;
    o.method = Method::Newton;
    const Parameters p = resolve_parameters(A, o);  // Ω2 = diag(A) by default: must be positive
    ratio_ = p.omega1.cwiseQuotient(p.omega2);
    fallback_options_.method = Method::NRM;
    fallback_options_.omega1 = p.omega1;
    fallback_options_.omega2 = p.omega2;
    fallback_options_.inner = options.inner == Inner::CG ? Inner::Auto : options.inner;  // nrm factorizes
  }

  /// The prolongations below this level (P[0]: the next coarser level → this one), for the
  /// multigrid-preconditioned CG inner solve; they must outlive this level.
  void use_hierarchy(Prolongations<StorageIndex> below) { below_ = below; }

  const MatrixType& matrix() const { return A_; }
  Eigen::Index size() const { return A_.rows(); }

  /// The reduced system of the (shifted) LCP, analysed once.
  System& lcp_system() {
    if (!lcp_system_) lcp_system_ = std::make_unique<System>(A_, nullptr, inner_, below_);
    return *lcp_system_;
  }
  std::unique_ptr<System> affine_system(const RowMatrix& B) const { return std::make_unique<System>(A_, &B, inner_, below_); }
  const char* inner_name() const { return lcp_system_ ? lcp_system_->inner_name() : "none"; }

  /// Res of z; w = Az + q and g = z − ζ(z) (ζ = Bz + c, or 0 when B is null).
  double evaluate(const Vector& z, const Vector& q, const RowMatrix* B, const Vector* c, Vector& w, Vector& g) const {
    w.noalias() = A_ * z;
    w += q;
    if (B) {
      g.noalias() = -(*B * z);
      g += z - *c;
    } else {
      g = z;
    }
    return stable_norm(w.cwiseMin(g));
  }

  /// Ω1 (g/Ω1 − w/Ω2) = g − (Ω1/Ω2) w: the modulus vector x up to the factor γ/(2Ω1).
  void modulus(const Vector& w, const Vector& g, Vector& x) const { x = g - ratio_.cwiseProduct(w); }

  /// The inactive set ℐ = {x > 0} = {g/Ω1 − w/Ω2 > 0}.
  void active_set(const Vector& w, const Vector& g, std::vector<char>& inactive) const {
    inactive.resize(static_cast<std::size_t>(w.size()));
    for (Eigen::Index i = 0; i < w.size(); ++i) inactive[i] = (g[i] - ratio_[i] * w[i]) > 0;
  }

  /// Up to `sweeps` sweeps of the fallback member (nrm) from z0 for ICP(q, A, ζ); the best iterate.
  Result sweep(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector& z0, int sweeps, double tol) {
    if (!fallback_) fallback_.emplace(A_, fallback_options_);  // factorizes Ω2 + AΩ1 once
    Options it = fallback_options_;
    it.tol = tol > 0 ? tol : std::numeric_limits<double>::min();
    it.maxiter = sweeps;
    it.stall_iterations = std::max(1, sweeps);
    return fallback_->solve(q, zeta, &z0, {}, {}, &it);
  }
  Result sweep(const Vector& q, const RowMatrix* B, const Vector* c, const Vector& z0, int sweeps, double tol) {
    using Z = Zeta<StorageIndex>;
    return sweep(q, B ? Z::affine(*B, *c) : Z::none(), z0, sweeps, tol);
  }

 private:
  const MatrixType& A_;
  Inner inner_;
  Vector ratio_;  // Ω1/Ω2: x > 0 ⇔ g − (Ω1/Ω2) w > 0
  Options fallback_options_;
  std::unique_ptr<System> lcp_system_;
  Prolongations<StorageIndex> below_;
  std::optional<Solver<MatrixType>> fallback_;
};

/// The globalized Newton loop on one level for the (shifted) LCP (B null) or the affine ICP
/// ζ(z) = Bz + c, with the reduced system `K` (analysed for this problem), from z.
template <typename MatrixType>
NewtonOutcome newton_loop(NewtonLevel<MatrixType>& level, ActiveSetSystem<typename MatrixType::StorageIndex>& K,
                          const Eigen::VectorXd& q, const typename NewtonLevel<MatrixType>::RowMatrix* B,
                          const Eigen::VectorXd* c, Eigen::VectorXd z, const NewtonControl& ctl) {
  using Vector = Eigen::VectorXd;
  static const Vector no_shift;
  const Eigen::Index n = level.size();
  NewtonOutcome o;
  // The family's Monitor decides convergence, divergence, the callback, the Ctrl-C poll and keeps
  // the history and the best iterate; Newton's own ends (a settled active set, a fallback that
  // brings nothing, maxiter Newton steps) are decided here.
  Options mo;
  mo.tol = ctl.tol;
  mo.maxiter = std::numeric_limits<int>::max();
  mo.record_history = ctl.record_history;
  mo.verbose = ctl.verbose;
  Result mres;
  Monitor monitor(mo, ctl.callback, ctl.poll, ctl.progress, ctl.shift ? *ctl.shift : no_shift, mres, n);
  Iterate s;  // what the Monitor reads: z, and x up to the factor γ/2 (Ω1⁻¹g − Ω2⁻¹w, times Ω1)
  const Vector z_start = z;
  Vector w(n), g(n), rhs(n), z_new(n), w_new(n), g_new(n), x_new(n);
  double r = level.evaluate(z, q, B, c, w, g);
  o.z = z;  // the best iterate, where a fallback starts
  o.residual = r;
  std::vector<char> inactive;
  std::unordered_set<std::uint64_t> seen;
  std::uint64_t last_set = 0;
  bool have_last = false, exempt = true;
  int sweep_run = 10, k = 0;
  NonMonotone test(r);
  auto observe = [&]() -> bool {  // iterate k to the Monitor; true: stop (mres.status says why)
    level.modulus(w, g, x_new);
    s.step = s.x.size() ? (x_new - s.x).template lpNorm<Eigen::Infinity>() : std::numeric_limits<double>::infinity();
    s.x.swap(x_new);
    s.z = z;
    return monitor.stop(k++, r, s);
  };
  auto accept = [&](double r_new) {
    z.swap(z_new); w.swap(w_new); g.swap(g_new); r = r_new;
    if (r < o.residual || !std::isfinite(o.residual)) { o.residual = r; o.z = z; }
    test.push(r);
  };
  // Sweeps of the fallback member from the best iterate; false when not allowed or no better iterate came.
  auto fall_back = [&]() -> bool {
    if (o.sweeps >= ctl.sweep_budget) return false;
    const int sweeps = std::min(sweep_run, ctl.sweep_budget - o.sweeps);
    sweep_run *= 2;
    const Result fr = level.sweep(q, B, c, o.z, sweeps, ctl.tol);
    o.sweeps += fr.iterations;
    seen.clear();
    have_last = false;
    exempt = true;
    if (!(fr.residual < o.residual)) return false;
    z_new = fr.z;
    const double r_fb = level.evaluate(z_new, q, B, c, w_new, g_new);
    test.reset(r_fb);
    z.swap(z_new); w.swap(w_new); g.swap(g_new); r = r_fb;
    if (r < o.residual) { o.residual = r; o.z = z; }
    return true;
  };
  std::optional<Status> own;  // an end decided here, not by the Monitor
  while (!observe()) {
    if (o.steps >= ctl.maxiter) { own = Status::MaxIterations; break; }
    if (o.steps == 0 && !ctl.start_set.empty() && o.sweeps == 0)
      inactive = ctl.start_set;
    else
      level.active_set(w, g, inactive);
    const std::uint64_t h = hash_set(inactive);
    if (have_last && h == last_set) {  // z solves its own active set's system: exact to rounding
      o.settled = true;
      own = Status::Stagnated;
      break;
    }
    bool ok = seen.insert(h).second;  // a set seen before: a cycle
    if (ok && K.factorize(inactive)) {
      for (Eigen::Index i = 0; i < n; ++i) rhs[i] = inactive[i] ? -q[i] : (c ? (*c)[i] : 0.0);
      z_new = z;  // the start of an iterative inner solve (inner = cg), which stops at tol / 10
      o.inner_iterations += K.solve(rhs, z_new, std::max(0.1 * ctl.tol, ctl.forcing * r));
      ++o.solves;
      ++o.steps;
      const double r_new = level.evaluate(z_new, q, B, c, w_new, g_new);
      ok = std::isfinite(r_new) && (exempt || test.acceptable(r_new));
      if (ok) {
        // z did not move beyond rounding: only ties (g ≈ w ≈ 0) changed sides; nothing left to gain.
        const double dz = (z_new - z).template lpNorm<Eigen::Infinity>();
        const bool still = dz <= 1e-14 * z_new.template lpNorm<Eigen::Infinity>();
        accept(r_new);
        o.inactive = inactive;
        last_set = h;
        have_last = true;
        exempt = false;
        if (still && !(r < ctl.tol)) {  // report this iterate, then end: nothing left to gain
          if (!observe()) {
            o.settled = true;
            own = Status::Stagnated;
          }
          break;
        }
        continue;
      }
    }
    if (!fall_back()) {
      own = o.sweeps >= ctl.sweep_budget && ctl.sweep_budget > 0 ? Status::MaxIterations : Status::Stagnated;
      break;
    }
  }
  if (own) monitor.result().status = *own;
  monitor.finish(z_start);
  o.z = std::move(mres.z);
  o.residual = mres.residual;
  o.status = mres.status;
  o.message = std::move(mres.message);
  o.history_iteration = std::move(mres.history_iteration);
  o.history_seconds = std::move(mres.history_seconds);
  o.history_residual = std::move(mres.history_residual);
  return o;
}

}  // namespace detail

/// The Newton member. Set-up once (coarse operators PᵀAP, symbolic analyses on first use);
/// solve(q, ζ) many times. `A` is held by reference and must outlive the object. Concurrent
/// solves on one object are serialized (the factorizations are reused state).
///
/// `prolongations` P_0, P_1, ...: P_0 maps level 1 (n_1 unknowns) to the finest level (n), P_l
/// level l+1 to level l. Coarse problems A_{l+1} = P_lᵀ A_l P_l, q_{l+1} = P_lᵀ q_l are solved
/// coarse to fine, each solution prolongated, projected onto z ≥ ζ and used as the next start.
template <typename MatrixType>
class Newton {
 public:
  using StorageIndex = typename MatrixType::StorageIndex;
  using Vector = Eigen::VectorXd;
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  using Callback = detail::Callback;
  using Poll = detail::Poll;
  using Progress = detail::Progress;

  Newton(const MatrixType& A, Options options, std::vector<RowMatrix> prolongations = {})
      : A_(A), options_(std::move(options)), P_(std::move(prolongations)) {
    if (A.rows() != A.cols())
      throw std::invalid_argument("Newton: A must be square, got " + std::to_string(A.rows()) + "x" +
                                  std::to_string(A.cols()));
    options_.check(A.rows());
    const auto t0 = std::chrono::steady_clock::now();
    Options o = options_;
    o.method = Method::Newton;
    params_ = resolve_parameters(A_, o);
    finest_ = std::make_unique<detail::NewtonLevel<MatrixType>>(A_, options_);
    Eigen::Index rows = A.rows();
    for (std::size_t l = 0; l < P_.size(); ++l) {
      if (P_[l].rows() != rows || P_[l].cols() < 1 || P_[l].cols() > rows)
        throw std::invalid_argument("Newton: prolongations[" + std::to_string(l) + "] has shape " +
                                    std::to_string(P_[l].rows()) + "x" + std::to_string(P_[l].cols()) +
                                    ", expected " + std::to_string(rows) + " rows and at most as many columns");
      rows = P_[l].cols();
    }
    // Galerkin coarse operators; a level whose operator has a non-positive diagonal ends the
    // hierarchy there (the active-set test needs Ω2 = diag > 0).
    const RowMatrix* fine = nullptr;
    for (std::size_t l = 0; l < P_.size(); ++l) {
      const RowMatrix AP = fine ? detail::product(*fine, P_[l]) : detail::product(A_, P_[l]);
      R_.emplace_back(P_[l].transpose());
      auto Ac = std::make_unique<RowMatrix>(detail::product(R_.back(), AP));
      if (!(diagonal(*Ac).array() > 0).all()) { P_.resize(l); R_.resize(l); break; }
      Options co;
      co.inner = options_.inner;
      coarse_matrices_.push_back(std::move(Ac));
      coarse_.push_back(std::make_unique<detail::NewtonLevel<RowMatrix>>(*coarse_matrices_.back(), co));
      fine = coarse_matrices_.back().get();
    }
    detail::Prolongations<StorageIndex> below{P_.data(), R_.data(), P_.size()};
    finest_->use_hierarchy(below);
    for (auto& level : coarse_) level->use_hierarchy(below = below.below());
    setup_seconds_ = detail::ScopedTimer::seconds_since(t0);
  }

  const Options& options() const { return options_; }
  /// Ω1, Ω2 (of the active-set test x > 0 ⇔ (z − ζ)/Ω1 > w/Ω2) and γ with defaults resolved.
  const Parameters& parameters() const { return params_; }
  /// The inner solver of the reduced systems ("none" before the first solve).
  const char* inner_name() const { return finest_->inner_name(); }
  /// Number of levels (1 without prolongations).
  int levels() const { return 1 + static_cast<int>(coarse_.size()); }

  /// Solves ICP(q, A, ζ). The start: with prolongations, the nested coarse-to-fine solution
  /// (z0 is not used: measured on the American put, n_space = 6400, a warm start from the previous
  /// time step moved the exercise boundary one node per step, 38.7 steps per time step, while the
  /// nested start took 1.2); without, z0 (zeros when null). The iteration fields of
  /// `iteration_options` (tol, maxiter, record_history) override the constructor's.
  Result solve(const Vector& q, const Zeta<StorageIndex>& zeta = Zeta<StorageIndex>::none(), const Vector* z0 = nullptr,
               const Callback& callback = {}, const Poll& poll = {}, const Options* iteration_options = nullptr,
               const Progress& progress = {}) const {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto t0 = std::chrono::steady_clock::now();
    Options o = options_;
    if (iteration_options) {
      iteration_options->check(A_.rows());
      o.tol = iteration_options->tol;
      o.maxiter = iteration_options->maxiter;
      o.record_history = iteration_options->record_history;
      o.verbose = iteration_options->verbose;
    }
    return run(q, zeta, z0, callback, poll, o, !coarse_.empty(), progress);
  }

  /// Polish: one Newton step from z on its active set (no nesting). Returns the better of z and
  /// the step (smaller Res); `success()` when that Res is below `tol`.
  Result polish(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector& z, double tol) const {
    std::lock_guard<std::mutex> lock(mutex_);
    Options o = options_;
    o.tol = tol;
    o.maxiter = 1;
    o.record_history = false;
    return run(q, zeta, &z, {}, {}, o, false);
  }

 private:
  Result run(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0, const Callback& callback,
             const Poll& poll, const Options& o, bool nest, const Progress& progress = {}) const {
    const auto t0 = std::chrono::steady_clock::now();
    const Eigen::Index n = A_.rows();
    if (q.size() != n) throw std::invalid_argument("Newton::solve: q has length " + std::to_string(q.size()) + ", expected n = " + std::to_string(n));
    if (z0 && z0->size() != n) throw std::invalid_argument("Newton::solve: x0 has length " + std::to_string(z0->size()) + ", expected n = " + std::to_string(n));
    zeta.check(n);
    Run run(*this, o, callback, poll, nest, progress);
    Result r;
    switch (zeta.kind()) {
      case ZetaKind::None: r = run.obstacle(q, Vector::Zero(n), z0, nest); break;
      case ZetaKind::Constant: r = run.obstacle(q, zeta.c(), z0, nest); break;
      case ZetaKind::Affine: r = run.affine(q, zeta, z0); break;
      case ZetaKind::Functor: r = zeta.has_jacobian() ? run.semismooth(q, zeta, z0) : run.functor(q, zeta, z0); break;
    }
    r.timings.setup = setup_seconds_;
    r.timings.total = detail::ScopedTimer::seconds_since(t0);
    r.inner = finest_->inner_name();
    return r;
  }

  using Level = detail::NewtonLevel<MatrixType>;
  using CoarseLevel = detail::NewtonLevel<RowMatrix>;

  /// One solve: the statistics it gathers over levels and outer steps.
  struct Run {
    const Newton& self;
    const Options& o;
    const Callback& callback;
    const Poll& poll;
    bool nest;  // start from the nested coarse-to-fine solution
    const Progress& progress;
    Result res;
    Run(const Newton& s, const Options& opts, const Callback& cb, const Poll& p, bool nested, const Progress& pr)
        : self(s), o(opts), callback(cb), poll(p), nest(nested), progress(pr) {
      res.level_steps.assign(s.levels(), 0);
      res.level_seconds.assign(s.levels(), 0.0);
    }

    /// `report`: this loop is the problem being solved (history, callback), not an inner one.
    detail::NewtonControl finest_control(const Vector& shift, double tol, int maxiter, bool report) const {
      detail::NewtonControl c;
      c.tol = tol;
      c.maxiter = maxiter;
      c.sweep_budget = o.maxiter;
      c.record_history = report && o.record_history;
      if (report) {  // the callback's k counts on from the steps before this loop, as absorb()'s history does
        if (callback)
          c.callback = [&cb = callback, base = res.nit](int k, const Vector& z, double r) { return cb(base + k, z, r); };
        c.progress = progress;
        c.verbose = o.verbose;
      }
      c.shift = &shift;
      c.poll = poll;
      return c;
    }
    void absorb(const detail::NewtonOutcome& out, int level, double seconds) {
      res.level_steps[level] += out.steps;
      res.level_seconds[level] += seconds;
      res.linear_solves += out.solves;
      res.inner_iterations += out.inner_iterations;
      if (level == 0) {
        res.fallback_sweeps += out.sweeps;
        const int base = res.nit;
        for (std::size_t i = 0; i < out.history_iteration.size(); ++i) {
          res.history_iteration.push_back(base + out.history_iteration[i]);
          res.history_seconds.push_back(out.history_seconds[i]);
          res.history_residual.push_back(out.history_residual[i]);
        }
        res.nit += out.steps;
        res.iterations += out.steps + out.sweeps;
      }
    }

    /// Newton steps per coarse level. Nested iteration needs only a good start from each coarse
    /// level, not its exact solution. Measured on obstacle_2d m = 511 (n = 261k, one run, CPU s):
    /// to a settled set (≤ 100 steps) amg 25 solves, geometric 19, finest 3 steps both; 2 steps per
    /// coarse level: amg 18 solves, geometric 17, finest still 3, the AMG level 1 (n = 131k,
    /// denser than the finest) 2.2 instead of 2.8 s; 1 step: amg 10 finest steps (worse).
    static constexpr int coarse_steps = 2;
    /// The inner solves on the coarse levels stop at this fraction of the iterate's Res: a start
    /// needs no more. Measured on obstacle_2d (m = 255, 511, 1023, hierarchy geometric and amg,
    /// inner cg, tol 1e-8): CG iterations on all levels 36 → 20, 55 → 22, 74 → 25 (and 33 → 16,
    /// 55 → 22, 76 → 27 with amg) against 1e-12 relative; the finest-level step counts (3, or 2)
    /// and Res unchanged; 1e-4 and 1e-2 gave 39 and 30 at m = 1023.
    static constexpr double coarse_forcing = 0.1;

    /// Nested start for LCP(q_shift, A) in y ≥ 0: `coarse_steps` Newton steps per coarse level,
    /// coarse to fine.
    Vector nested_start(const Vector& q_shift) {
      const std::size_t L = self.coarse_.size();
      std::vector<Vector> qs(L + 1);
      qs[0] = q_shift;
      for (std::size_t l = 0; l < L; ++l) qs[l + 1] = self.R_[l] * qs[l];
      Vector y = Vector::Zero(L ? self.coarse_.back()->size() : q_shift.size());
      for (std::size_t l = L; l >= 1; --l) {
        const auto t0 = std::chrono::steady_clock::now();
        CoarseLevel& lev = *self.coarse_[l - 1];
        detail::NewtonControl c;
        c.maxiter = coarse_steps;
        c.forcing = coarse_forcing;
        c.sweep_budget = 1000;
        const auto out = detail::newton_loop(lev, lev.lcp_system(), qs[l], nullptr, nullptr, y, c);
        absorb(out, static_cast<int>(l), detail::ScopedTimer::seconds_since(t0));
        y = (self.P_[l - 1] * out.z).cwiseMax(0.0);  // prolongate, project onto y ≥ 0
      }
      return y;
    }

    /// The obstacle problem z ≥ ψ (ψ = 0: the LCP) as LCP(q + Aψ, A) in y = z − ψ.
    /// `nest`: without z0, start from the nested solution.
    /// `set` (optional): the inactive set to start from, replaced by the final one.
    Result obstacle(const Vector& q, const Vector& psi, const Vector* z0, bool nest, double tol = -1,
                    int maxiter = -1, bool report = true, std::vector<char>* set = nullptr) {
      Vector q_shift = q;
      q_shift.noalias() += self.A_ * psi;
      Vector y0 = z0 ? Vector((*z0 - psi).cwiseMax(0.0)) : Vector::Zero(q.size());
      if (nest && !self.coarse_.empty()) y0 = nested_start(q_shift);
      const auto t0 = std::chrono::steady_clock::now();
      auto control = finest_control(psi, tol >= 0 ? tol : o.tol, maxiter >= 0 ? maxiter : o.maxiter, report);
      auto out = [&] {
        if (!set || set->empty()) return detail::newton_loop(*self.finest_, self.finest_->lcp_system(), q_shift,
                                                             nullptr, nullptr, y0, control);
        // The previous set is a guess: tried without fallback; when its steps are rejected (on
        // impulse_control(101) they were, every outer step: Res 3.2, stagnated), the loop is
        // rerun from y0 on y0's own active set, as without a guess.
        auto guess = control;
        guess.start_set = *set;
        guess.sweep_budget = 0;
        auto tried = detail::newton_loop(*self.finest_, self.finest_->lcp_system(), q_shift, nullptr, nullptr, y0,
                                         guess);
        if (tried.settled || tried.status != Status::Stagnated || tried.steps >= control.maxiter) return tried;
        absorb(tried, 0, 0.0);
        control.maxiter -= tried.steps;
        return detail::newton_loop(*self.finest_, self.finest_->lcp_system(), q_shift, nullptr, nullptr, y0, control);
      }();
      if (set && !out.inactive.empty()) *set = out.inactive;
      absorb(out, 0, detail::ScopedTimer::seconds_since(t0));
      return finish(out, out.z + psi, q);
    }

    /// ζ(z) = Bz + c: Newton on the full system, from the obstacle problem with ψ = ζ(z0) (or
    /// from z0 itself when it is given and there is no nesting).
    Result affine(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0) {
      const Eigen::Index n = q.size();
      Vector psi(n);
      zeta.eval(z0 ? *z0 : Vector::Zero(n), psi);
      const Vector start = (z0 && !nest) ? *z0 : obstacle(q, psi, z0, nest, 0.0, std::min(100, o.maxiter), false).z;
      const auto t0 = std::chrono::steady_clock::now();
      auto K = self.finest_->affine_system(zeta.B());
      const Vector& c = zeta.c();
      const auto out = detail::newton_loop(*self.finest_, *K, q, &zeta.B(), &c, start,
                                           finest_control(Vector::Zero(n), o.tol, o.maxiter, true));
      absorb(out, 0, detail::ScopedTimer::seconds_since(t0));
      return finish(out, out.z, q);
    }

    /// A callable ζ: the outer fixed point z ← S(ζ(z)), S(ψ) = the obstacle problem's solution,
    /// each solved by Newton warm-started from z (nested the first time); an outer step that
    /// does not reduce Res hands over to sweeps of the fallback member on the ICP.
    Result functor(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0) {
      const Eigen::Index n = q.size();
      Vector z = z0 ? *z0 : Vector::Zero(n), psi(n), w(n);
      auto icp_res = [&](const Vector& v, Vector& zv) -> double { return icp_residual(q, zeta, v, zv, w); };
      double r = icp_res(z, psi);
      Result best;
      best.z = z;
      best.residual = r;
      if (std::isnan(r)) return zeta_failed(best, q);
      bool first = true;
      int sweep_run = 10;
      detail::NonMonotone test(r);
      std::vector<char> set;  // the last inner solve's inactive set: the next one starts from it
      Status status = Status::MaxIterations;
      const auto t0 = std::chrono::steady_clock::now();
      for (;;) {
        const bool asked = record(z, r, t0);
        if (r < o.tol) { status = Status::Converged; break; }
        if (asked) { status = Status::CallbackStop; break; }
        if (res.nit >= o.maxiter) { status = Status::MaxIterations; break; }
        if (poll) poll();
        // The inner obstacle problem, solved to a settled active set (its own tol: 0).
        // The first inner solve without z0 starts at y = 0 (z = ψ): measured better than from z = 0.
        Result inner = obstacle(q, psi, (first && !z0) ? nullptr : &z, first && nest, 0.0, o.maxiter - res.nit, false,
                                &set);
        first = false;
        ++res.outer_iterations;
        Vector psi_new(n);
        const double r_new = icp_res(inner.z, psi_new);
        if (std::isnan(r_new)) return zeta_failed(best, q);
        if (test.acceptable(r_new)) {
          z = inner.z; psi = psi_new; r = r_new;
          test.push(r);
          if (r < best.residual) { best.z = z; best.residual = r; }
          continue;
        }
        if (const auto stop = fallback(q, zeta, best, sweep_run, z)) { status = *stop; break; }
        r = icp_res(z, psi);
        test.reset(r);
        if (r < best.residual) { best.z = z; best.residual = r; }
      }
      Result out;
      out.z = best.z;
      out.residual = best.residual;
      out.status = status;
      return finish_outer(out, q);
    }

    /// A callable ζ with its Jacobian J: semismooth Newton on the whole ICP. A step is the affine
    /// step for the linearization ζ(z) + J(v − z) (B = J, c = ζ(z) − Jz, a new pattern each
    /// step); Res is the ICP's. Start as for an affine ζ.
    Result semismooth(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0) {
      const Eigen::Index n = q.size();
      Vector psi(n), w(n), g(n), rhs(n), z_new(n), psi_new(n), w_new(n), g_new(n);
      Result best;
      best.z = z0 ? *z0 : Vector::Zero(n);
      if (!zeta.eval(best.z, psi)) return zeta_failed(best, q);
      Vector z = (z0 && !nest) ? *z0 : obstacle(q, psi, z0, nest, 0.0, std::min(100, o.maxiter), false).z;
      auto icp_res = [&](const Vector& v, Vector& zv, Vector& wv, Vector& gv) -> double {
        const double r = icp_residual(q, zeta, v, zv, wv);
        if (!std::isnan(r)) gv = v - zv;
        return r;
      };
      double r = icp_res(z, psi, w, g);
      if (std::isnan(r)) return zeta_failed(best, q);
      best.z = z;
      best.residual = r;
      detail::NonMonotone test(r);
      bool exempt = true;
      int sweep_run = 10;
      Status status = Status::MaxIterations;
      RowMatrix J;
      std::vector<char> inactive;
      const auto t0 = std::chrono::steady_clock::now();
      for (;;) {
        const bool asked = record(z, r, t0);
        if (r < o.tol) { status = Status::Converged; break; }
        if (asked) { status = Status::CallbackStop; break; }
        if (poll) poll();
        if (res.nit >= o.maxiter) { status = Status::MaxIterations; break; }
        if (!zeta.jacobian(z, J)) return zeta_failed(best, q);
        const Vector c = psi - J * z;
        self.finest_->active_set(w, g, inactive);
        const auto t_step = std::chrono::steady_clock::now();
        auto K = self.finest_->affine_system(J);
        bool ok = K->factorize(inactive);
        if (ok) {
          for (Eigen::Index i = 0; i < n; ++i) rhs[i] = inactive[i] ? -q[i] : c[i];
          res.inner_iterations += K->solve(rhs, z_new);
          ++res.linear_solves; ++res.nit; ++res.iterations; ++res.level_steps[0];
          res.level_seconds[0] += detail::ScopedTimer::seconds_since(t_step);
          const double r_new = icp_res(z_new, psi_new, w_new, g_new);
          ok = std::isfinite(r_new) && (exempt || test.acceptable(r_new));
          if (ok) {
            z.swap(z_new); psi.swap(psi_new); w.swap(w_new); g.swap(g_new); r = r_new;
            test.push(r);
            exempt = false;
            if (r < best.residual) { best.z = z; best.residual = r; }
            continue;
          }
        }
        if (const auto stop = fallback(q, zeta, best, sweep_run, z)) { status = *stop; break; }
        r = icp_res(z, psi, w, g);
        test.reset(r);
        exempt = true;
        if (r < best.residual) { best.z = z; best.residual = r; }
      }
      Result out;
      out.z = best.z;
      out.residual = best.residual;
      out.status = status;
      return finish_outer(out, q);
    }

    /// Iterate res.nit of the outer iterations (finest level), z with Res r, into the history and
    /// to the callback (every iterate, the last one too, as the Monitor does); true when the
    /// callback asks to stop.
    bool record(const Vector& z, double r, std::chrono::steady_clock::time_point t0) {
      if (o.record_history) {
        res.history_iteration.push_back(res.nit);
        res.history_seconds.push_back(detail::ScopedTimer::seconds_since(t0));
        res.history_residual.push_back(r);
      }
      return callback && callback(res.nit, z, r);
    }

    /// Fallback of the outer iterations: sweeps of the fallback member on the whole ICP from the
    /// best iterate, each run twice as long as the last (`sweep_run`). Sets z to the sweeps' best
    /// iterate, or returns why to stop: maxiter fallback sweeps spent, or STAGNATED when the
    /// sweeps did not improve on the best Res.
    std::optional<Status> fallback(const Vector& q, const Zeta<StorageIndex>& zeta, const Result& best,
                                   int& sweep_run, Vector& z) {
      if (res.fallback_sweeps >= o.maxiter) return Status::MaxIterations;
      const int k = std::min(sweep_run, o.maxiter - res.fallback_sweeps);
      sweep_run *= 2;
      const Result sw = sweep_icp(q, zeta, best.z, k);
      res.fallback_sweeps += sw.iterations;
      res.iterations += sw.iterations;
      if (!(sw.residual < best.residual)) return Status::Stagnated;
      z = sw.z;
      return std::nullopt;
    }

    /// Res of the ICP at v (ζ(v) in zv, Av + q in wv): NaN only when ζ failed; +inf for a
    /// runaway v (non-finite, never handed to ζ) or an Av + q that overflowed.
    double icp_residual(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector& v, Vector& zv, Vector& wv) {
      constexpr double inf = std::numeric_limits<double>::infinity();
      if (!v.allFinite()) return inf;
      if (!zeta.eval(v, zv)) return std::numeric_limits<double>::quiet_NaN();
      wv.noalias() = self.A_ * v;
      wv += q;
      const double r = detail::stable_norm(wv.cwiseMin(v - zv));
      return std::isnan(r) ? inf : r;
    }

    Result sweep_icp(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector& z, int sweeps) {
      return self.finest_->sweep(q, zeta, z, sweeps, o.tol);
    }

    Result zeta_failed(const Result& best, const Vector& q) {
      Result out = res;
      out.status = Status::ZetaFailed;
      out.z = best.z;
      out.w = self.A_ * best.z + q;
      out.residual = std::numeric_limits<double>::quiet_NaN();
      out.message = to_string(out.status);
      return out;
    }

    /// The result of a finest-level loop: z (original variables), w, status and message.
    Result finish(const detail::NewtonOutcome& out, const Vector& z, const Vector& q) {
      Result r = res;
      r.z = z;
      r.w = self.A_ * z + q;
      r.residual = out.residual;
      r.status = out.status;
      r.message = out.message;
      if (out.settled && r.status == Status::Stagnated)
        r.message = "stagnated: the active set has settled and Res is at its rounding floor, above tol; "
                    "returning the best iterate";
      r.path = r.fallback_sweeps ? (r.nit ? "newton+fallback" : "fallback") : "newton";
      return r;
    }
    Result finish_outer(Result out, const Vector& q) {
      Result r = res;
      r.z = out.z;
      r.w = self.A_ * out.z + q;
      r.residual = out.residual;
      r.status = out.status;
      r.message = to_string(r.status);
      if (r.status != Status::Converged) r.message += "; returning the best iterate";
      r.path = r.fallback_sweeps ? (r.nit ? "newton+fallback" : "fallback") : "newton";
      return r;
    }
  };

  const MatrixType& A_;
  Options options_;
  Parameters params_;
  std::vector<RowMatrix> P_, R_;  // prolongations and their transposes
  std::vector<std::unique_ptr<RowMatrix>> coarse_matrices_;
  std::unique_ptr<Level> finest_;
  std::vector<std::unique_ptr<CoarseLevel>> coarse_;
  double setup_seconds_ = 0;
  mutable std::mutex mutex_;
};

}  // namespace nrmicp
