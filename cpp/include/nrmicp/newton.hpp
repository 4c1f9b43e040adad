// nrmicp — the Newton member: a semismooth Newton method on the modulus equation of Theorem 3.1,
//
//   F(x) = (Ω2 + AΩ1)x − (Ω2 − AΩ1)|x| + γ(Aζ + q) = 0,
//
// with nested iteration over user-supplied prolongations and a fallback to the paper's
// iteration (docs/SPEC.md, "The Newton member"). A step with D = diag(sign x) solves the piece
// of F on which x lies: with the inactive set ℐ = {x ≥ 0} (z − ζ > 0, w = 0) and the active set
// 𝒜 = {x < 0} (z − ζ = 0), i.e. x ≥ 0 ⇔ (z − ζ)/Ω1 ≥ w/Ω2 (ties: NewtonLevel::active_set):
//   (Az + q)_ℐ = 0,   (z − ζ(z))_𝒜 = 0            (detail/active_set.hpp)
// and x⁺ is recovered by the start formula x = γ/2 (Ω1⁻¹ g − Ω2⁻¹ w). For an LCP this is the
// primal–dual active-set method; on each piece F is affine, so the step is exact there.
//
// The structure: the step runs in the family's loop (detail::loop, solver.hpp) with the family's
// stopping Monitor, like every member's step.
//   detail/newton_level.hpp   one level: its matrix, the active-set test, the reduced systems, the
//                             fallback member
//   detail/newton_step.hpp    the plain step, with ζ's linearization as a policy: fixed (the
//                             shifted LCP, an affine ζ) or the Jacobian of a callable ζ at each z
//   detail/globalization.hpp  Globalized<Step>: non-monotone acceptance, cycles, fallback sweeps
//                             of nrm from the best iterate, and the step's own ends (settled
//                             active set, a fallback that brings nothing, maxiter Newton steps)
//   this file                 newton_loop (one level: step + wrapper + Monitor) and nrmicp::Newton,
//                             which orchestrates the levels of nested iteration, the start of an
//                             affine/semismooth solve, the outer fixed point on a callable ζ
//                             without Jacobian, and the result.
#pragma once

#include "detail/active_set.hpp"
#include "detail/globalization.hpp"
#include "detail/newton_level.hpp"
#include "detail/newton_step.hpp"
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
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace nrmicp {

namespace detail {

/// What the Newton loop on one level did, as a Result (z: the best iterate; its Res, status,
/// message and history; newton.linear_solves, .inner_iterations, .fallback_sweeps), and what
/// nested iteration and the outer fixed point take on from it.
struct LevelOutcome : Result {
  int steps = 0;               ///< Newton steps (the Monitor's nit is the best iterate's index)
  bool settled = false;        ///< the active set repeated: z solves the problem to rounding
  std::vector<char> inactive;  ///< the inactive set of z's last step (empty if no step was taken)
};

/// The Newton member on one level: the plain step `plain` (at its start), globalized, in the
/// family's loop (detail::loop, solver.hpp) with the family's Monitor.
template <typename Plain>
LevelOutcome newton_loop(Plain& plain, const NewtonControl& ctl) {
  static const Eigen::VectorXd no_shift;
  Options mo;
  mo.tol = ctl.tol;
  mo.maxiter = std::numeric_limits<int>::max();  // Newton steps are counted by the step (ctl.maxiter)
  mo.record_history = ctl.record_history;
  mo.verbose = ctl.verbose;
  LevelOutcome o;
  Monitor monitor(mo, ctl.callback, ctl.poll, ctl.progress, ctl.shift ? *ctl.shift : no_shift, o, plain.size());
  const Eigen::VectorXd z_start = plain.z();
  Iterate s;
  Globalized<Plain> step(plain, ctl, s);
  loop(step, s, monitor);
  monitor.finish(z_start);
  o.steps = plain.steps();
  o.settled = step.settled();
  o.inactive = step.inactive();
  o.newton.fallback_sweeps = step.sweeps();
  o.newton.linear_solves = plain.solves();
  o.newton.inner_iterations = plain.inner_iterations();
  return o;
}

/// The (shifted) LCP (B null) or the affine ICP ζ(z) = Bz + c on `level`, with the reduced system
/// `K` (analysed for this problem), from z.
template <typename MatrixType>
LevelOutcome newton_loop(NewtonLevel<MatrixType>& level, ActiveSetSystem<typename MatrixType::StorageIndex>& K,
                          const Eigen::VectorXd& q, const typename NewtonLevel<MatrixType>::RowMatrix* B,
                          const Eigen::VectorXd* c, Eigen::VectorXd z, const NewtonControl& ctl) {
  NewtonStep<MatrixType, FixedLinearization<MatrixType>> plain(level, {level, K, q, B, c}, std::move(z));
  return newton_loop(plain, ctl);
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

  /// `options.method` is taken as Method::Newton (this class is the Newton member), so the
  /// options the Newton member does not have (phi, accelerate, z_update) are refused.
  Newton(const MatrixType& A, Options options, std::vector<RowMatrix> prolongations = {})
      : A_(A), options_(as_newton(std::move(options))) {
    if (A.rows() != A.cols())
      throw std::invalid_argument("Newton: A must be square, got " + std::to_string(A.rows()) + "x" +
                                  std::to_string(A.cols()));
    options_.check(A.rows());
    const auto t0 = std::chrono::steady_clock::now();
    params_ = resolve_parameters(A_, options_);
    finest_ = std::make_unique<detail::NewtonLevel<MatrixType>>(A_, options_);
    Eigen::Index rows = A.rows();
    for (std::size_t l = 0; l < prolongations.size(); ++l) {
      const RowMatrix& P = prolongations[l];
      if (P.rows() != rows || P.cols() < 1 || P.cols() > rows)
        throw std::invalid_argument("Newton: prolongations[" + std::to_string(l) + "] has shape " +
                                    std::to_string(P.rows()) + "x" + std::to_string(P.cols()) +
                                    ", expected " + std::to_string(rows) + " rows and at most as many columns");
      rows = P.cols();
    }
    // Galerkin coarse operators; a level whose operator has a non-positive diagonal ends the
    // hierarchy there (the active-set test needs Ω2 = diag > 0).
    for (auto& P : prolongations) {
      const RowMatrix AP = hierarchy_.empty() ? detail::product(A_, P) : detail::product(hierarchy_.back().A, P);
      detail::Level<StorageIndex> level{std::move(P), {}, {}};
      level.R = level.P.transpose();
      level.A = detail::product(level.R, AP);
      if (!(diagonal(level.A).array() > 0).all()) break;
      hierarchy_.push_back(std::move(level));
    }
    Options co;
    co.inner = options_.inner;
    for (auto& level : hierarchy_) coarse_.push_back(std::make_unique<detail::NewtonLevel<RowMatrix>>(level.A, co));
    detail::Hierarchy<StorageIndex> below{hierarchy_.data(), hierarchy_.size()};
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

  /// Solves ICP(q, A, ζ). The start: with prolongations, the nested coarse-to-fine solution (z0
  /// is not used; warm starts win only on small time-stepping problems: README, the American
  /// put); without, z0 (zeros when null). `solve_options`, when given, replace the constructor's
  /// per-solve options (SolveOptions says which the Newton member uses).
  Result solve(const Vector& q, const Zeta<StorageIndex>& zeta = Zeta<StorageIndex>::none(), const Vector* z0 = nullptr,
               const Callback& callback = {}, const Poll& poll = {}, const SolveOptions* solve_options = nullptr,
               const Progress& progress = {}) const {
    std::lock_guard<std::mutex> lock(mutex_);
    const Options o = solve_options ? options_.with(solve_options, A_.rows()) : options_;
    return run(q, zeta, z0, callback, poll, o, !coarse_.empty(), progress);
  }

  /// Polish: Newton steps from z on its active set (no nesting) until Res < tol or Res reaches
  /// its rounding floor (the rule of the Newton loop: the set repeats, or a step does not reduce
  /// Res there; STAGNATED, the message gives the floor), at most polish_steps. Returns the best
  /// iterate, z included.
  Result polish(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector& z, double tol) const {
    std::lock_guard<std::mutex> lock(mutex_);
    Options o = options_;
    o.tol = tol;
    o.maxiter = polish_steps;
    o.record_history = false;
    return run(q, zeta, &z, {}, {}, o, false);
  }

 private:
  /// One step lands a member's answer on the rounding floor; a second one shows it is there.
  static constexpr int polish_steps = 3;

  Result run(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0, const Callback& callback,
             const Poll& poll, const Options& o, bool nest, const Progress& progress = {}) const {
    const auto t0 = std::chrono::steady_clock::now();
    const Eigen::Index n = A_.rows();
    if (q.size() != n) throw std::invalid_argument("Newton::solve: q has length " + std::to_string(q.size()) + ", expected n = " + std::to_string(n));
    if (z0 && z0->size() != n) throw std::invalid_argument("Newton::solve: x0 has length " + std::to_string(z0->size()) + ", expected n = " + std::to_string(n));
    zeta.check(n);
    Options resolved = o;
    resolve_tolerance(resolved, q, zeta);
    Run run(*this, resolved, callback, poll, nest, progress);
    Result r;
    const auto t_iterations = std::chrono::steady_clock::now();
    switch (zeta.kind()) {
      case ZetaKind::None: r = run.solve_obstacle(q, Vector::Zero(n), z0, nest); break;
      case ZetaKind::Constant: r = run.solve_obstacle(q, zeta.c(), z0, nest); break;
      case ZetaKind::Affine: r = run.solve_affine(q, zeta, z0); break;
      case ZetaKind::Functor:
        r = zeta.has_jacobian() ? run.solve_semismooth(q, zeta, z0) : run.solve_outer_fixed_point(q, zeta, z0);
        break;
    }
    r.timings.iterations = detail::ScopedTimer::seconds_since(t_iterations);  // all levels, nested start included
    r.timings.setup = setup_seconds_;
    r.timings.total = detail::ScopedTimer::seconds_since(t0);
    r.inner = finest_->inner_name();
    return r;
  }

  static Options as_newton(Options o) {
    o.method = Method::Newton;
    return o;
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
      res.newton.level_steps.assign(s.levels(), 0);
      res.newton.level_seconds.assign(s.levels(), 0.0);
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
    void absorb(const detail::LevelOutcome& out, int level, double seconds) {
      res.newton.level_steps[level] += out.steps;
      res.newton.level_seconds[level] += seconds;
      res.newton.linear_solves += out.newton.linear_solves;
      res.newton.inner_iterations += out.newton.inner_iterations;
      if (level == 0) {
        res.newton.fallback_sweeps += out.newton.fallback_sweeps;
        const int base = res.nit;
        for (std::size_t i = 0; i < out.history_iteration.size(); ++i) {
          res.history_iteration.push_back(base + out.history_iteration[i]);
          res.history_seconds.push_back(out.history_seconds[i]);
          res.history_residual.push_back(out.history_residual[i]);
        }
        res.nit += out.steps;
        res.iterations += out.steps + out.newton.fallback_sweeps;
      }
    }

    /// Newton steps per coarse level: until its active set settles (at most this many), since a
    /// cut-short coarse solve leaves a band of wrong active set that Res does not show
    /// (measured: docs/MEASUREMENTS.md, coarse_maxiter).
    static constexpr int coarse_maxiter = 100;
    /// The inner solves on the coarse levels stop at this fraction of the iterate's Res: a start
    /// needs no more; not on the finest level (docs/MEASUREMENTS.md, coarse_forcing).
    static constexpr double coarse_forcing = 0.1;

    /// Nested start for LCP(q_shift, A) in y ≥ 0: Newton on each coarse level to a settled active set,
    /// coarse to fine.
    Vector nested_start(const Vector& q_shift) {
      const std::size_t L = self.coarse_.size();
      std::vector<Vector> qs(L + 1);
      qs[0] = q_shift;
      for (std::size_t l = 0; l < L; ++l) qs[l + 1] = self.hierarchy_[l].R * qs[l];
      Vector y = Vector::Zero(L ? self.coarse_.back()->size() : q_shift.size());
      for (std::size_t l = L; l >= 1; --l) {
        const auto t0 = std::chrono::steady_clock::now();
        CoarseLevel& lev = *self.coarse_[l - 1];
        detail::NewtonControl c;
        c.maxiter = coarse_maxiter;
        c.forcing = coarse_forcing;
        c.sweep_budget = 1000;
        const auto out = detail::newton_loop(lev, lev.lcp_system(), qs[l], nullptr, nullptr, y, c);
        absorb(out, static_cast<int>(l), detail::ScopedTimer::seconds_since(t0));
        y = (self.hierarchy_[l - 1].P * out.z).cwiseMax(0.0);  // prolongate, project onto y ≥ 0
      }
      return y;
    }

    /// The obstacle problem z ≥ ψ (ψ = 0: the LCP) as LCP(q + Aψ, A) in y = z − ψ.
    /// `nest`: without z0, start from the nested solution.
    /// `set` (optional): the inactive set to start from, replaced by the final one.
    Result solve_obstacle(const Vector& q, const Vector& psi, const Vector* z0, bool nest, double tol = -1,
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
    Result solve_affine(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0) {
      const Eigen::Index n = q.size();
      Vector psi(n);
      zeta.eval(z0 ? *z0 : Vector::Zero(n), psi);
      const Vector start =
          (z0 && !nest) ? *z0 : solve_obstacle(q, psi, z0, nest, 0.0, std::min(100, o.maxiter), false).z;
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
    Result solve_outer_fixed_point(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0) {
      const Eigen::Index n = q.size();
      Vector z = z0 ? *z0 : Vector::Zero(n), psi(n), psi_new(n), w(n);
      double r = icp_residual(q, zeta, z, psi, w);
      Result best;
      best.z = z;
      best.residual = r;
      if (std::isnan(r)) return zeta_failed(best, q);
      int sweep_run = 10;
      detail::NonMonotone test(r);
      std::vector<char> set;  // the last inner solve's inactive set: the next one starts from it
      Status status = Status::MaxIterations;
      const auto t0 = std::chrono::steady_clock::now();
      for (bool first = true;; first = false) {
        const bool asked = record(z, r, t0);
        if (r < o.tol) { status = Status::Converged; break; }
        if (asked) { status = Status::CallbackStop; break; }
        if (res.nit >= o.maxiter) break;
        if (poll) poll();
        // The inner obstacle problem, solved to a settled active set (its own tol: 0).
        // The first inner solve without z0 starts at y = 0 (z = ψ): measured better than from z = 0.
        Result inner = solve_obstacle(q, psi, (first && !z0) ? nullptr : &z, first && nest, 0.0,
                                      o.maxiter - res.nit, false, &set);
        ++res.newton.outer_iterations;
        const double r_new = icp_residual(q, zeta, inner.z, psi_new, w);
        if (std::isnan(r_new)) return zeta_failed(best, q);
        if (test.acceptable(r_new)) {
          z = inner.z; psi.swap(psi_new); r = r_new;
          test.push(r);
        } else {
          if (const auto stop = fallback(q, zeta, best, sweep_run, z)) { status = *stop; break; }
          r = icp_residual(q, zeta, z, psi, w);
          test.reset(r);
        }
        if (r < best.residual) { best.z = z; best.residual = r; }
      }
      best.status = status;
      return finish_outer(best, q);
    }

    /// A callable ζ with its Jacobian J: semismooth Newton on the whole ICP, each step the affine
    /// step of the linearization ζ(z) + J(v − z) (detail::JacobianLinearization); Res is the
    /// ICP's. Start as for an affine ζ. Newton steps and fallback sweeps of the start count
    /// against maxiter.
    Result solve_semismooth(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0) {
      using Step = detail::NewtonStep<MatrixType, detail::JacobianLinearization<MatrixType>>;
      const Eigen::Index n = q.size();
      Vector psi(n);
      Result best;
      best.z = z0 ? *z0 : Vector::Zero(n);
      if (!zeta.eval(best.z, psi)) return zeta_failed(best, q);
      Vector start =
          (z0 && !nest) ? *z0 : solve_obstacle(q, psi, z0, nest, 0.0, std::min(100, o.maxiter), false).z;
      const auto t0 = std::chrono::steady_clock::now();
      Step plain(*self.finest_, {*self.finest_, q, zeta, {}, {}, {}}, std::move(start));
      if (std::isnan(plain.residual())) return zeta_failed(best, q);
      static const Vector no_shift;
      auto control = finest_control(no_shift, o.tol, o.maxiter - res.nit, true);
      control.sweep_budget = o.maxiter - res.newton.fallback_sweeps;
      const auto out = detail::newton_loop(plain, control);
      absorb(out, 0, detail::ScopedTimer::seconds_since(t0));
      return finish(out, out.z, q);
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
      if (res.newton.fallback_sweeps >= o.maxiter) return Status::MaxIterations;
      const int k = std::min(sweep_run, o.maxiter - res.newton.fallback_sweeps);
      sweep_run = std::min(sweep_run, std::numeric_limits<int>::max() / 2) * 2;  // no overflow to a negative run
      const Result sw = self.finest_->sweep(q, zeta, best.z, k, o.tol);
      res.newton.fallback_sweeps += sw.iterations;
      res.iterations += sw.iterations;
      if (!(sw.residual < best.residual)) return Status::Stagnated;
      z = sw.z;
      return std::nullopt;
    }

    double icp_residual(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector& v, Vector& zv, Vector& wv) {
      return self.finest_->icp_residual(q, zeta, v, zv, wv);
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
    Result finish(const detail::LevelOutcome& out, const Vector& z, const Vector& q) {
      return finish(z, out.residual, out.status, out.message, q);
    }
    /// The result of the outer fixed point: its best iterate.
    Result finish_outer(const Result& best, const Vector& q) {
      std::string message = to_string(best.status);
      if (best.status != Status::Converged) message += "; returning the best iterate";
      return finish(best.z, best.residual, best.status, std::move(message), q);
    }
    Result finish(const Vector& z, double residual, Status status, std::string message, const Vector& q) {
      Result r = res;
      r.z = z;
      r.w = self.A_ * z + q;
      r.residual = residual;
      r.status = status;
      r.message = std::move(message);
      r.newton.path = r.newton.fallback_sweeps ? (r.nit ? "newton+fallback" : "fallback") : "newton";
      return r;
    }
  };

  const MatrixType& A_;
  Options options_;
  Parameters params_;
  std::vector<detail::Level<StorageIndex>> hierarchy_;  // the levels below the finest: P, R, A
  std::unique_ptr<Level> finest_;
  std::vector<std::unique_ptr<CoarseLevel>> coarse_;
  double setup_seconds_ = 0;
  mutable std::mutex mutex_;
};

}  // namespace nrmicp
