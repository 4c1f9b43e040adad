// nrmicp — what a solve returns.
#pragma once

#include <Eigen/Core>

#include <cmath>
#include <limits>
#include <map>
#include <string>
#include <vector>

namespace nrmicp {

enum class Status {
  Converged = 0,      ///< Res(z) < tol
  MaxIterations = 1,  ///< maxiter x-updates (Newton: Newton steps, or fallback sweeps) done without reaching tol
  Diverged = 2,       ///< Res became non-finite or grew beyond divergence_factor × best
  Stagnated = 3,      ///< Res stopped decreasing before tol (the rules of Options::stall_iterations; Newton: also
                      ///< a fallback that did not improve the best Res, or a settled active set short of tol)
  CallbackStop = 4,   ///< the callback asked to stop
  ZetaFailed = 5,     ///< ζ(z) returned non-finite values
};

/// The status's name, as Python's nrmicp.Status spells it.
inline const char* status_name(Status s) {
  switch (s) {
    case Status::Converged: return "CONVERGED";
    case Status::MaxIterations: return "MAX_ITERATIONS";
    case Status::Diverged: return "DIVERGED";
    case Status::Stagnated: return "STAGNATED";
    case Status::CallbackStop: return "CALLBACK_STOP";
    case Status::ZetaFailed: return "ZETA_FAILED";
  }
  return "?";
}
inline constexpr Status all_statuses[] = {Status::Converged,  Status::MaxIterations, Status::Diverged,
                                          Status::Stagnated,  Status::CallbackStop,  Status::ZetaFailed};

/// What the status means (the start of Result::message).
inline const char* to_string(Status s) {
  switch (s) {
    case Status::Converged: return "converged: Res < tol";
    case Status::MaxIterations: return "maximum number of iterations reached";
    case Status::Diverged: return "diverged: Res became non-finite or grew without bound";
    case Status::Stagnated: return "stagnated: Res stopped decreasing before reaching tol";
    case Status::CallbackStop: return "stopped by the callback";
    case Status::ZetaFailed: return "zeta(z) returned non-finite values";
  }
  return "?";
}

/// Wall-clock seconds by phase, of the call that returned them (a constructor's are its
/// setup_timings()). `setup` and `iterations` are disjoint parts of `total`; `factorization` lies
/// in setup + iterations; `zeta`, `spmv` and `inner_solve` lie in `iterations` (docs/SPEC.md, "Timings").
struct Timings {
  double setup = 0;          ///< set-up done in this call: a lazy factorization of A; Newton: the reduced
                             ///< systems' patterns and symbolic analyses (or V-cycle set-up), the hierarchy's
                             ///< operators formed again
  double factorization = 0;  ///< numeric factorizations (Lm, A; Newton: each step's reduced system or its
                             ///< V-cycle's update, a callable ζ's per-step system, the fallback member's)
  double iterations = 0;     ///< the iteration loop of this solve (Newton: all levels, without their set-up)
  double zeta = 0;           ///< evaluating ζ (and its Jacobian)
  double spmv = 0;           ///< products with A (and ζ's B, two-sweep's N2); for the AOR types on a
                             ///< row-major A the one-pass sweep (product + forward substitution) is here,
                             ///< for Newton the projected Gauss–Seidel sweeps
  double inner_solve = 0;    ///< solves with Lm and A (factor or triangular); Newton: the reduced solves
  double total = 0;          ///< this call, from entry to return
};

/// The Newton member's statistics (newton.hpp; polish); zero/empty for the stationary members.
/// The Python result takes every field of this struct by name (reflection over the binding).
struct NewtonStats {
  int linear_solves = 0;               ///< reduced linear systems solved, on all levels
  long long inner_iterations = 0;      ///< iterations of the iterative inner solve (inner = "cg"), all levels
  int fallback_sweeps = 0;             ///< sweeps of the fallback member (nrm) on the finest level
  int outer_iterations = 0;            ///< callable ζ: outer fixed-point steps on ζ
  std::vector<int> level_steps;        ///< Newton steps per level of nested iteration, finest first
  std::vector<double> level_seconds;   ///< seconds per level, finest first
  std::string path;                    ///< "newton", "newton+fallback" (Newton steps and fallback sweeps), "fallback",
                                       ///< "newton+outer" (ζ's Jacobian did not deliver: the outer fixed point took over)
};

struct Result {
  Eigen::VectorXd z;         ///< best iterate (smallest Res seen); the last one when converged
  Eigen::VectorXd w;         ///< A z + q
  Status status = Status::MaxIterations;
  int nit = 0;               ///< x-updates performed to reach the returned z (Newton: finest-level Newton steps)
  int iterations = 0;        ///< x-updates performed in all (Newton: finest-level Newton steps + fallback sweeps)
  double residual = 0;       ///< Res(z) of the returned z
  std::string message;
  std::string inner;         ///< the inner solver used for Lm (Newton: for the reduced systems)
  // history (filled when Options::record_history)
  std::vector<int> history_iteration;
  std::vector<double> history_seconds;
  std::vector<double> history_residual;
  Timings timings;
  /// Counts a step kind reports beyond the iterations (e.g. linear solves), by name.
  std::map<std::string, long long> counters;
  NewtonStats newton;        ///< the Newton member's statistics (empty for the stationary members)
  bool success() const { return status == Status::Converged; }
};

namespace detail {
/// Every member's last check of the iterate it returns, with w = Az + q formed: a w that overflowed
/// is no certificate (Res reads min(w, z − ζ(z)), blind to w = +inf: ζ ≡ 1e308 reported CONVERGED
/// with w = inf), so such a result is DIVERGED with Res = +inf; a NaN Res (the products of an
/// overflowing iterate) is +inf. Left alone: ZETA_FAILED, whose Res is undefined.
inline void refuse_overflow(Result& r) {
  if (r.status == Status::ZetaFailed) return;
  if (r.w.allFinite() && r.z.allFinite()) {
    if (std::isnan(r.residual)) r.residual = std::numeric_limits<double>::infinity();
    return;
  }
  r.residual = std::numeric_limits<double>::infinity();
  if (r.status == Status::Converged || r.status == Status::Stagnated) {
    r.status = Status::Diverged;
    r.message = std::string(to_string(r.status)) + ": A z + q overflowed at the returned iterate (|w_i| > 1.8e308); scale the data";
  }
}
}  // namespace detail

}  // namespace nrmicp
