// nrmicp — Method 3.1 of the paper, written once for every splitting:
//
//   x⁽ᵏ⁺¹⁾ = x⁽ᵏ⁾ + Lm⁻¹ [Ω2(|x⁽ᵏ⁾| − x⁽ᵏ⁾) − γ(A ẑ + q)],   ẑ = ζ(z⁽ᵏ⁾) + Ω1(|x⁽ᵏ⁾| + x⁽ᵏ⁾)/γ,
//
// which is the paper's Lm x⁽ᵏ⁺¹⁾ = (N + φ)Ω1 x⁽ᵏ⁾ + (Ω2 − AΩ1)|x⁽ᵏ⁾| − γAζ(z⁽ᵏ⁾) − γq with
// N = M − A rearranged (no cancellation of large terms). See docs/SPEC.md.
#pragma once

#include "detail/anderson.hpp"
#include "detail/sweep.hpp"
#include "detail/timer.hpp"
#include "inner_solver.hpp"
#include "options.hpp"
#include "result.hpp"
#include "splitting.hpp"
#include "zeta.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <mutex>
#include <optional>
#include <stdexcept>

namespace nrmicp {


/// Set-up (splitting, factorization) once; solve(q, ζ) many times.
/// `A` is held by reference: it must outlive the Solver (as with Eigen's solvers).
template <typename MatrixType>
class Solver {
 public:
  using StorageIndex = typename MatrixType::StorageIndex;
  using Vector = Eigen::VectorXd;
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  /// Called after every iterate with (k, z⁽ᵏ⁾, Res); return true to stop.
  using Callback = std::function<bool(int, const Vector&, double)>;
  /// Called about every 50 ms during a solve; may throw to abort (e.g. on Ctrl-C).
  using Poll = std::function<void()>;

  Solver(const MatrixType& A, Options options) : A_(A), options_(std::move(options)) {
    if (A.rows() != A.cols())
      throw std::invalid_argument("Solver: A must be square, got " + std::to_string(A.rows()) + "x" +
                                  std::to_string(A.cols()));
    options_.check(A.rows());
    const auto t0 = std::chrono::steady_clock::now();
    params_ = resolve_parameters(A, options_);
    {
      detail::ScopedTimer t(setup_factorization_);
      splitting_.emplace(A, options_.method, params_, options_.inner);
    }
    if (options_.z_update == ZUpdate::Solve) factorize_A();
    setup_seconds_ = detail::ScopedTimer::seconds_since(t0);
  }

  const Options& options() const { return options_; }
  const Parameters& parameters() const { return params_; }
  const char* inner_name() const { return splitting_->inner_name(); }
  const Splitting<StorageIndex>& splitting() const { return *splitting_; }

  /// Solves ICP(q, A, ζ) from the initial guess z0 (zeros when null). The iteration fields of
  /// `iteration_options` (tol, maxiter, z_update, accelerate, anderson_m, theta, record_history,
  /// stall_iterations, divergence_factor) override the constructor's; the splitting stays.
  Result solve(const Vector& q, const Zeta<StorageIndex>& zeta = Zeta<StorageIndex>::none(),
               const Vector* z0 = nullptr, const Callback& callback = {}, const Poll& poll = {},
               const Options* iteration_options = nullptr) const {
    const auto t0 = std::chrono::steady_clock::now();
    const Eigen::Index n = A_.rows();
    Options o = options_;
    if (iteration_options) {
      iteration_options->check(n);
      o.tol = iteration_options->tol; o.maxiter = iteration_options->maxiter;
      o.z_update = iteration_options->z_update; o.accelerate = iteration_options->accelerate;
      o.anderson_m = iteration_options->anderson_m; o.theta = iteration_options->theta;
      o.record_history = iteration_options->record_history;
      o.stall_iterations = iteration_options->stall_iterations;
      o.divergence_factor = iteration_options->divergence_factor;
    }
    if (q.size() != n) throw std::invalid_argument("Solver::solve: q has length " + std::to_string(q.size()) + ", expected n = " + std::to_string(n));
    if (z0 && z0->size() != n) throw std::invalid_argument("Solver::solve: x0 has length " + std::to_string(z0->size()) + ", expected n = " + std::to_string(n));
    zeta.check(n);
    Result r;
    if (zeta.kind() == ZetaKind::Constant) {
      // ζ ≡ c: LCP(q + Ac, A) in y = z − c. Res and w are the same in both variables.
      Vector q_shift = q;
      q_shift.noalias() += A_ * zeta.c();
      // y0 = z0 − c (z0 = 0 by default), so that the iterates are exactly those of the ICP.
      const Vector y0 = z0 ? Vector(*z0 - zeta.c()) : Vector(-zeta.c());
      r = iterate(q_shift, Zeta<StorageIndex>::none(), &y0, callback, poll, o, zeta.c());
      r.z += zeta.c();
    } else {
      r = iterate(q, zeta, z0, callback, poll, o, Vector());
    }
    r.timings.setup = setup_seconds_;
    r.timings.factorization += setup_factorization_;
    r.timings.total = detail::ScopedTimer::seconds_since(t0);
    r.inner = splitting_->inner_name();
    return r;
  }

 private:
  void factorize_A() const {
    std::lock_guard<std::mutex> lock(a_mutex_);
    if (a_solver_.ready()) return;
    detail::ScopedTimer t(a_factorization_);
    a_solver_.compute(ColMatrix(A_), options_.inner, "A (for the z-update 'solve')");
  }

  // The loop. `shift` is the constant obstacle (only to report z to the callback), or empty.
  Result iterate(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0, const Callback& callback,
                 const Poll& poll, const Options& o, const Vector& shift) const {
    using clock = std::chrono::steady_clock;
    const Eigen::Index n = A_.rows();
    const bool lcp = zeta.kind() == ZetaKind::None;
    // Auto = Explicit: measured faster (no solve with A: 4-10x on ICPs at equal iteration
    // counts) and more robust (it converged on unshifted-Laplacian and thermoforming ICPs where
    // Solve stagnated). Except the paper's NRM (Ω2 = I, far from diag A) on an ICP: there
    // Explicit stagnated on Bai's ICPs and Solve converged (~145 iterations). Solve is also
    // needed when ζ's Lipschitz constant is about 1 (README). MMS is the Zheng–Vong baseline,
    // whose definition includes the Solve update: Auto keeps it (else it equals NRMGS).
    const bool paper_update = !lcp && ((options_.method == Method::NRM && options_.omega2.size() == 0) ||
                                       options_.method == Method::MMS);
    const ZUpdate zu = o.z_update != ZUpdate::Auto ? o.z_update : (paper_update ? ZUpdate::Solve : ZUpdate::Explicit);
    Result res;
    Timings& tm = res.timings;
    if (zu == ZUpdate::Solve) {
      const double before = a_factorization_;
      factorize_A();
      tm.factorization += a_factorization_ - before;  // only if this solve paid for it
    }
    const auto t_start = clock::now();
    const Vector& om1 = params_.omega1;
    const bool omega1_is_identity = (om1.array() == 1.0).all();
    const Vector& om2 = params_.omega2;
    const double gamma = params_.gamma;

    Vector x(n), absx, z(n), Az(n), zeta_z = Vector::Zero(n), zeta_prev = Vector::Zero(n);
    Vector zhat(n), Azhat(n), rhs(n), dx(n), absx_prev, x_plain, x_next, best_z(n), tmp(n);

    auto spmv = [&](const Vector& v, Vector& out) { detail::ScopedTimer t(tm.spmv); out.noalias() = A_ * v; };
    bool zeta_ok = true;
    auto eval_zeta = [&](const Vector& v, Vector& out) {
      if (lcp) return;
      detail::ScopedTimer t(tm.zeta);
      zeta_ok = zeta.eval(v, out);
    };
    // out = ζ-part + Ω1(|x| + x)/γ (no ζ-part for an LCP): the explicit z-update and ẑ.
    auto from_modulus = [&](const Vector* zeta_part, Vector& out) {
      if (zeta_part) {
        for (Eigen::Index i = 0; i < n; ++i) out[i] = (*zeta_part)[i] + om1[i] * (std::abs(x[i]) + x[i]) / gamma;
      } else {
        for (Eigen::Index i = 0; i < n; ++i) out[i] = om1[i] * (std::abs(x[i]) + x[i]) / gamma;
      }
    };
    // z from x (and, for the explicit update, ζ of the previous z).
    auto compute_z = [&]() {
      if (zu == ZUpdate::Explicit) {
        from_modulus(lcp ? nullptr : &zeta_prev, z);
      } else {
        for (Eigen::Index i = 0; i < n; ++i) tmp[i] = om2[i] * (std::abs(x[i]) - x[i]) / gamma - q[i];
        detail::ScopedTimer t(tm.inner_solve);
        a_solver_.solve(tmp, z);
      }
    };
    // LCP with the explicit update and a row-major (CSR) A: the product, Res and the next
    // right-hand side rhs = Ω2(|x| − x) − γ(Az + q) in one pass over A (ẑ = z here). The whole
    // iteration is memory-bound, so passes over n-vectors cost as much as the flops.
    constexpr bool row_major = MatrixType::IsRowMajor;
    const bool fused = row_major && lcp && zu == ZUpdate::Explicit;
    auto evaluate_fused = [&]() -> double {
      detail::ScopedTimer t(tm.spmv);
      double s = 0;
      for (Eigen::Index i = 0; i < n; ++i) {
        double a = 0;
        for (typename MatrixType::InnerIterator it(A_, i); it; ++it) a += it.value() * z[it.index()];
        const double wi = a + q[i];
        const double m = std::min(wi, z[i]);
        s += m * m;
        rhs[i] = om2[i] * (std::abs(x[i]) - x[i]) - gamma * wi;
      }
      return std::sqrt(s);
    };
    // Az, ζ(z) and Res for the current z, in one pass after the product (no w, g temporaries).
    auto evaluate = [&]() -> double {
      if (fused) return evaluate_fused();
      spmv(z, Az);
      eval_zeta(z, zeta_z);
      double s = 0;
      if (lcp) {
        for (Eigen::Index i = 0; i < n; ++i) { const double m = std::min(Az[i] + q[i], z[i]); s += m * m; }
      } else {
        for (Eigen::Index i = 0; i < n; ++i) { const double m = std::min(Az[i] + q[i], z[i] - zeta_z[i]); s += m * m; }
      }
      return std::sqrt(s);
    };

    // Start: x⁽⁰⁾ = γ/2 (Ω1⁻¹(z0 − ζ(z0)) − Ω2⁻¹(Az0 + q)).
    {
      Vector zs = z0 ? *z0 : Vector::Zero(n);
      Vector zeta0 = Vector::Zero(n);
      eval_zeta(zs, zeta0);
      if (!zeta_ok) {
        res.status = Status::ZetaFailed; res.z = zs; res.w = A_ * zs + q;
        res.residual = std::numeric_limits<double>::quiet_NaN();
        res.message = std::string(to_string(res.status)) + " at the initial guess";
        return res;
      }
      spmv(zs, Az);
      x = gamma / 2 * ((zs - zeta0).cwiseQuotient(om1) - (Az + q).cwiseQuotient(om2));
      zeta_prev = zeta0;
    }
    compute_z();

    const bool anderson = o.accelerate == Accelerate::Anderson;
    std::optional<detail::Anderson> aa;
    if (anderson) aa.emplace(o.anderson_m);
    bool aa_pending = false;  // x came from an Anderson step not yet checked
    if (splitting_->two_sweep()) absx_prev = x.cwiseAbs();

    double best = std::numeric_limits<double>::infinity(), prev_res = best, last_step = best;
    int best_k = 0, floor_count = 0, win_count = 0, bad_windows = 0;
    double win_min = std::numeric_limits<double>::infinity(), win_max = -win_min, prev_win_min = win_min;
    auto last_poll = t_start;
    const bool two_sweep = splitting_->two_sweep();
    res.status = Status::MaxIterations;

    // The AOR-type members with the explicit update on a row-major A run as one sweep over A
    // per iteration (detail/sweep.hpp): it returns Res(z⁽ᵏ⁾) and has already made x⁽ᵏ⁺¹⁾ and
    // z⁽ᵏ⁺¹⁾ (in z_next), which are simply not used when the loop stops at k. With Anderson,
    // the sweep's plain step is mixed and z is recomputed from the mixed x.
    const bool sweep = row_major && is_aor_type(options_.method) && !two_sweep && params_.theta == 1 &&
                       zu == ZUpdate::Explicit;
    Vector z_next, x_before;
    if (sweep) z_next.resize(n);
    auto run_sweep = [&]() -> double {
      if (!lcp) {
        eval_zeta(z, zeta_z);
        if (!zeta_ok) return std::numeric_limits<double>::quiet_NaN();
        from_modulus(&zeta_z, zhat);
      }
      if constexpr (row_major) {
        detail::ScopedTimer t(tm.spmv);  // the sweep is the product with A (and the triangular solve)
        return detail::aor_sweep(A_, z, lcp ? nullptr : &zeta_z, lcp ? nullptr : &zhat, q, om1, omega1_is_identity, om2,
                                 splitting_->left_inverse_diagonal(), splitting_->lower_scale(), gamma, x, z_next, dx,
                                 last_step);
      } else {
        return std::numeric_limits<double>::quiet_NaN();  // unreachable: sweep needs row-major
      }
    };

    for (int k = 0;; ++k) {
      if (sweep && anderson) x_before = x;  // the sweep advances x in place
      double r = sweep ? run_sweep() : evaluate();
      if (aa_pending && zeta_ok && !(r < prev_res)) {
        // Safeguard: the accelerated step did not reduce Res; take the plain step instead.
        x = x_plain;
        aa->reset();
        compute_z();
        if (sweep) x_before = x;
        r = sweep ? run_sweep() : evaluate();
      }
      aa_pending = false;
      if (!zeta_ok) { res.status = Status::ZetaFailed; res.iterations = k; break; }
      if (o.record_history) {
        res.history_iteration.push_back(k);
        res.history_seconds.push_back(detail::ScopedTimer::seconds_since(t_start));
        res.history_residual.push_back(r);
      }
      // Stagnation, two ways. (1) At the rounding floor: Res does not improve while the steps
      // are at rounding level. (2) No progress: in 3 consecutive windows of stall_iterations
      // iterates, the smallest Res of a window is not below the previous window's (a cycle, or a
      // slow divergence). Windows, not the global best: Res may jump up at first and then fall
      // steadily (nrmm on the American put). A window of bit-identical Res is neutral: the
      // iteration can sit on such a plateau for thousands of steps while x moves towards the
      // solution (measured on the impulse-control and thermoforming scenes).
      // The best iterate is kept by swapping buffers, not copying: z is rewritten by the next
      // z-update, and the step below does not read it.
      const bool improved = r < best;
      if (improved) {
        best = r; best_k = k; best_z.swap(z); floor_count = 0;
      } else if (k > 0) {
        const double xnorm = x.template lpNorm<Eigen::Infinity>();
        floor_count = (last_step <= 1e-8 * (xnorm > 0 ? xnorm : 1.0)) ? floor_count + 1 : 0;
      }
      win_min = std::min(win_min, r);
      win_max = std::max(win_max, r);
      if (++win_count == o.stall_iterations) {
        if (win_max != win_min) bad_windows = (win_min < prev_win_min) ? 0 : bad_windows + 1;
        prev_win_min = win_min;
        win_min = std::numeric_limits<double>::infinity();
        win_max = -win_min;
        win_count = 0;
      }
      res.iterations = k;
      if (r < o.tol) { res.status = Status::Converged; break; }
      if (!std::isfinite(r) || r > o.divergence_factor * best) { res.status = Status::Diverged; break; }
      if (floor_count >= o.stall_iterations || bad_windows >= 3) {
        res.status = Status::Stagnated;
        break;
      }
      if (callback) {
        bool stop;
        const Vector& zk = improved ? best_z : z;
        if (shift.size()) stop = callback(k, zk + shift, r); else stop = callback(k, zk, r);
        if (stop) { res.status = Status::CallbackStop; break; }
      }
      if (poll && detail::ScopedTimer::seconds_since(last_poll) > 0.05) { poll(); last_poll = clock::now(); }
      if (k >= o.maxiter) { res.status = Status::MaxIterations; break; }
      prev_res = r;
      if (sweep) {  // x⁽ᵏ⁺¹⁾ is made; take z⁽ᵏ⁺¹⁾
        if (!anderson) {
          z.swap(z_next);
          continue;
        }
        // Anderson on the sweep: its workspace dx is exactly the plain step x⁽ᵏ⁺¹⁾ − x⁽ᵏ⁾.
        x_plain = x;
        aa->step(x_before, dx, x_next);
        last_step = (x_next - x_before).template lpNorm<Eigen::Infinity>();
        x.swap(x_next);
        aa_pending = true;
        if (!lcp) zeta_prev.swap(zeta_z);  // ζ(z⁽ᵏ⁾) for the explicit update
        compute_z();
        continue;
      }

      // One step of Method 3.1: rhs = Ω2(|x| − x) − γ(A ẑ + q), x += Lm⁻¹ rhs.
      if (!fused) {
        const Vector* Azh = &Az;  // LCP, explicit update: ẑ = z exactly, no second product
        if (!(lcp && zu == ZUpdate::Explicit)) {
          from_modulus(&zeta_z, zhat);
          spmv(zhat, Azhat);
          Azh = &Azhat;
        }
        for (Eigen::Index i = 0; i < n; ++i) rhs[i] = om2[i] * (std::abs(x[i]) - x[i]) - gamma * ((*Azh)[i] + q[i]);
      }
      if (two_sweep) {
        absx = x.cwiseAbs();
        detail::ScopedTimer t(tm.spmv);
        rhs.noalias() -= splitting_->n2() * (absx - absx_prev);
        absx_prev.swap(absx);
      }
      {
        detail::ScopedTimer t(tm.inner_solve);
        splitting_->solve(rhs, dx);
      }
      const double theta = params_.theta;
      if (anderson) {
        if (theta != 1) dx *= theta;
        x_plain = x + dx;
        aa->step(x, dx, x_next);
        last_step = (x_next - x).template lpNorm<Eigen::Infinity>();
        x.swap(x_next);
        aa_pending = true;
      } else {
        double step = 0;
        for (Eigen::Index i = 0; i < n; ++i) {
          const double d = theta * dx[i];
          x[i] += d;
          step = std::max(step, std::abs(d));
        }
        last_step = step;
      }
      if (!lcp) zeta_prev.swap(zeta_z);  // ζ(z⁽ᵏ⁾) for the explicit update of z⁽ᵏ⁺¹⁾
      compute_z();
    }

    tm.iterations = detail::ScopedTimer::seconds_since(t_start);
    if (!std::isfinite(best)) best_z = z;  // no finite Res was ever seen
    res.nit = (res.status == Status::Converged) ? res.iterations : best_k;
    res.z = best_z;
    // w and Res of the returned iterate, recomputed (honest even if it is not the last one).
    spmv(res.z, Az);
    res.w = Az + q;
    if (std::isfinite(best)) {
      res.residual = best;
    } else {
      res.residual = std::numeric_limits<double>::quiet_NaN();
    }
    res.message = to_string(res.status);
    if (res.status != Status::Converged && res.status != Status::ZetaFailed)
      res.message += "; returning the best iterate (iteration " + std::to_string(best_k) + ")";
    if (res.status == Status::ZetaFailed) res.message += " at iteration " + std::to_string(res.iterations);
    return res;
  }

  const MatrixType& A_;
  Options options_;
  Parameters params_;
  std::optional<Splitting<StorageIndex>> splitting_;
  double setup_seconds_ = 0, setup_factorization_ = 0;
  mutable std::mutex a_mutex_;
  mutable InnerSolver<StorageIndex> a_solver_;
  mutable double a_factorization_ = 0;
};

/// One call: set up and solve.
template <typename MatrixType>
Result solve(const MatrixType& A, const Eigen::VectorXd& q,
             const Zeta<typename MatrixType::StorageIndex>& zeta = Zeta<typename MatrixType::StorageIndex>::none(),
             const Options& options = Options(), const Eigen::VectorXd* z0 = nullptr) {
  return Solver<MatrixType>(A, options).solve(q, zeta, z0);
}

}  // namespace nrmicp
