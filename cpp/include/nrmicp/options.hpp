// nrmicp — options of Method 3.1 and its family.
#pragma once

#include <Eigen/Core>

#include <algorithm>
#include <array>
#include <cfloat>
#include <cmath>
#include <iterator>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>

namespace nrmicp {

/// The members of the family (paper §3) and the baselines it is compared with (§2).
/// Each fixes the splitting A = M − N; see docs/SPEC.md for the table.
enum class Method {
  NRM,       ///< M = A, Ω1 = Ω2 = I (paper); Lm factorized once
  NRMM,      ///< M = A, Ω1 = I, Ω2 = αI; Lm factorized once
  NRMAOR,    ///< M = (D − βL)/α; Lm lower triangular (forward substitution)
  NRMSOR,    ///< NRMAOR with β = α
  NRMGS,     ///< NRMAOR with α = β = 1
  NRMJ,      ///< NRMAOR with α = 1, β = 0; Lm diagonal
  MMS,       ///< Zheng–Vong modified modulus splitting: AOR splitting, Ω1 = I, φ = 0
  TwoSweep,  ///< two-sweep modulus method (Wu–Li form), M1 = (D − βL)/α, M2 = D − U, relaxation θ
  Newton,    ///< semismooth Newton on the modulus equation (newton.hpp): one reduced linear solve per step
};

/// How z⁽ᵏ⁾ is recovered from the modulus vector x⁽ᵏ⁾.
enum class ZUpdate {
  Auto,      ///< Explicit, but Solve on an ICP for the paper's NRM (Ω2 = I) and for MMS (README "Options", z_update)
  Explicit,  ///< z = ζ(z_prev) + Ω1(|x| + x)/γ — no solve with A
  Solve,     ///< A z = Ω2(|x| − x)/γ − q — the paper's Step 1 (a factorization of A)
};

/// How the linear systems are solved: the sparse factorization of Lm (NRM, NRMM), of A (Solve
/// z-update) and of the Newton member's reduced systems, or, for the Newton member only, CG /
/// BiCGSTAB. The AOR-type left matrices never need one: they are triangular or diagonal.
enum class Inner {
  Auto,      ///< CHOLMOD if symmetric positive definite, else UMFPACK; Eigen's solvers without SuiteSparse
  Cholmod,   ///< CHOLMOD supernodal LLᵀ (SuiteSparse)
  Umfpack,   ///< UMFPACK LU (SuiteSparse)
  EigenLLT,  ///< Eigen::SimplicialLLT (AMD ordering)
  EigenLU,   ///< Eigen::SparseLU (COLAMD ordering)
  CG,        ///< method newton only: the reduced systems by CG (SPD) or BiCGSTAB, multigrid-preconditioned (detail/multigrid.hpp)
};

/// The factorization `inner` asks for where one is needed (the fallback member, a direct retry):
/// the iterative choice 'cg' leaves it to Auto.
inline Inner direct_inner(Inner inner) { return inner == Inner::CG ? Inner::Auto : inner; }

/// Stabilizers beyond the paper.
enum class Accelerate {
  None,      ///< the plain fixed-point step
  Anderson,  ///< safeguarded Anderson acceleration of x ↦ x⁺ with memory `anderson_m`
};

inline const char* to_string(Method m);
inline const char* to_string(ZUpdate z);
inline const char* to_string(Accelerate a);

/// A number for an error message (%g: small values stay readable).
inline std::string to_text(double v) {
  std::ostringstream s;
  s << v;
  return s.str();
}

/// The options a solve may change: Solver::solve and Newton::solve take them whole, overriding
/// the set-up's. The Newton member uses tol, rtol, maxiter, record_history and verbose (its
/// globalization has its own stopping rules) and refuses z_update, theta and accelerate.
struct SolveOptions {
  double tol = 1e-8;               ///< stop when Res(z) = ‖min(Az + q, z − ζ(z))‖₂ < target(Res(0)) (scipy's atol)
  /// Relative tolerance (scipy.sparse.linalg's rtol): the target is max(tol, rtol · Res(0)),
  /// Res(0) = ‖min(q, −ζ(0))‖₂ the residual at z = 0 (scipy's ‖b‖: independent of the start).
  double rtol = 0.0;
  int maxiter = 10000;             ///< at most this many x-updates (Newton: Newton steps on the finest level)
  double theta = 1.0;              ///< relaxation of the two-sweep step, 0 < θ ≤ 2 (two_sweep only: others need 1)
  ZUpdate z_update = ZUpdate::Auto;
  Accelerate accelerate = Accelerate::None;
  int anderson_m = 5;              ///< Anderson memory (number of past differences kept)
  bool record_history = false;     ///< keep (iteration, seconds, Res) of every iterate
  /// STAGNATED after this many iterations without a better Res whose steps are at rounding level
  /// (tol below what floating point reaches), after 3 consecutive windows of this many
  /// iterations whose smallest Res does not improve on the previous windows' (a cycle), or when
  /// the best Res has not improved for 10 windows and, at the rate Res falls, would not be
  /// reached again within maxiter (detail/stopping.hpp). Plateaus of bit-identical Res are neutral,
  /// except that 5 of them in a row with x fixed, or with max|z| growing, end the solve at once.
  int stall_iterations = 100;
  /// DIVERGED when Res exceeds this factor times the best Res seen, or the modulus vector x grows
  /// by this factor while Res does not improve.
  double divergence_factor = 1e10;
  /// Progress report: 0 silent; k > 0 calls the solve's progress hook at the first iterate, then
  /// whenever k seconds have passed since the last report, and once at the end.
  int verbose = 0;
};

/// Every option, with its default: the set-up's (the method and its splitting, the inner
/// solver) and the defaults of the per-solve ones (SolveOptions). Vectors left empty take the
/// method's default (docs/SPEC.md); a NaN alpha/beta takes the method's default too.
struct Options : SolveOptions {
  Method method = Method::NRMGS;
  Eigen::VectorXd omega1;          ///< Ω1 (positive), length n or empty
  Eigen::VectorXd omega2;          ///< Ω2 (positive), length n or empty
  double gamma = 1.0;              ///< γ > 0
  Eigen::VectorXd phi;             ///< relaxation diagonal φ (≥ 0), length n or empty
  double alpha = std::numeric_limits<double>::quiet_NaN();  ///< AOR α (NRMM: Ω2 = αI)
  double beta = std::numeric_limits<double>::quiet_NaN();   ///< AOR β
  Inner inner = Inner::Auto;       ///< how the linear systems are solved (a sparse factorization, or 'cg': newton's iterative solve)

  /// These options with the per-solve ones replaced by `s` (when given), checked.
  Options with(const SolveOptions* s, Eigen::Index n) const {
    Options o = *this;
    if (s) static_cast<SolveOptions&>(o) = *s;
    o.check(n);
    return o;
  }

  /// The absolute Res target of a solve whose Res at z = 0 is `res0`: max(tol, rtol · res0).
  /// (A zero target, tol = 0 with Res(0) = 0, is the smallest normal number: z = 0 solves. A
  /// non-finite Res(0), where Az + q or ζ(0) overflowed, gives no scale: it counts as 0.)
  double target(double res0) const {
    const double t = std::max(tol, std::isfinite(res0) ? rtol * res0 : 0.0);
    return t > 0 ? t : DBL_MIN;
  }

  /// Throws std::invalid_argument naming the offending field, its value and what is accepted.
  void check(Eigen::Index n) const {
    auto fail = [](const std::string& msg) { throw std::invalid_argument("Options: " + msg); };
    auto num = [](double v) { return to_text(v); };
    if (!(rtol >= 0 && rtol < 1)) fail("rtol must lie in [0, 1), got " + num(rtol));
    if (!(tol > 0 || (rtol > 0 && tol == 0)) || !std::isfinite(tol))
      fail("tol must be a finite number > 0 (or 0 with rtol > 0), got " + num(tol));
    if (maxiter < 0) fail("maxiter must be >= 0, got " + std::to_string(maxiter));
    if (!(gamma > 0) || !std::isfinite(gamma)) fail("gamma must be a finite number > 0, got " + num(gamma));
    if (gamma < DBL_MIN) fail("gamma = " + num(gamma) + " is subnormal; it must be >= " + num(DBL_MIN));
    auto check_vec = [&](const Eigen::VectorXd& v, const char* name, bool strictly_positive) {
      if (v.size() == 0) return;
      if (v.size() != n)
        fail(std::string(name) + " must have length n = " + std::to_string(n) + ", got " + std::to_string(v.size()));
      for (Eigen::Index i = 0; i < n; ++i) {
        const double x = v[i];
        if (!std::isfinite(x) || (strictly_positive ? !(x > 0) : x < 0))
          fail(std::string(name) + "[" + std::to_string(i) + "] = " + num(x) + "; it must be finite and " +
               (strictly_positive ? "> 0" : ">= 0"));
        if (strictly_positive && x < DBL_MIN)  // 1/x overflows, and x·y loses its digits
          fail(std::string(name) + "[" + std::to_string(i) + "] = " + num(x) + " is subnormal; it must be >= " +
               num(DBL_MIN) + " (rescale the problem)");
      }
    };
    check_vec(omega1, "omega1", true);
    check_vec(omega2, "omega2", true);
    check_vec(phi, "phi", false);
    if (!std::isnan(alpha) && (!(alpha > 0) || !std::isfinite(alpha)))
      fail("alpha must be a finite number > 0, got " + num(alpha));
    if (!std::isnan(alpha) && alpha < DBL_MIN) fail("alpha = " + num(alpha) + " is subnormal; it must be >= " + num(DBL_MIN));
    if (!std::isnan(beta) && (!(beta >= 0) || !std::isfinite(beta)))
      fail("beta must be a finite number >= 0, got " + num(beta));
    if (!(theta > 0 && theta <= 2)) fail("theta must lie in (0, 2], got " + num(theta));
    if (theta != 1 && method != Method::TwoSweep)
      fail("theta is the relaxation of method 'two_sweep'; method '" + std::string(to_string(method)) +
           "' has none (got theta = " + num(theta) + ")");
    if (anderson_m < 1 || anderson_m > 100) fail("anderson_m must lie in [1, 100], got " + std::to_string(anderson_m));
    if (stall_iterations < 1) fail("stall_iterations must be >= 1, got " + std::to_string(stall_iterations));
    if (!(divergence_factor > 1)) fail("divergence_factor must be > 1, got " + num(divergence_factor));
    if (verbose < 0) fail("verbose must be >= 0 (seconds between progress lines; 0: silent), got " + std::to_string(verbose));
    if ((method == Method::MMS || method == Method::TwoSweep) && (omega1.size() || phi.size()))
      fail("method '" + std::string(to_string(method)) + "' fixes omega1 = I and phi = 0; use an NRM-family "
           "method to set them");
    if (method == Method::Newton) check_newton(fail);
  }

 private:
  /// The options of the stationary members that the Newton member does not have.
  template <typename Fail>
  void check_newton(const Fail& fail) const {
    if (phi.size()) fail("phi is a parameter of the stationary members; method 'newton' has none");
    if (accelerate != Accelerate::None)
      fail("accelerate='" + std::string(to_string(accelerate)) + "' applies to the stationary members; method "
           "'newton' takes Newton steps (use accelerate='none')");
    if (z_update != ZUpdate::Auto)
      fail("z_update='" + std::string(to_string(z_update)) + "' applies to the stationary members; method "
           "'newton' recovers z from its linear solves (use z_update='auto')");
  }
};

inline const char* to_string(Method m) {
  switch (m) {
    case Method::NRM: return "nrm";
    case Method::NRMM: return "nrmm";
    case Method::NRMAOR: return "nrmaor";
    case Method::NRMSOR: return "nrmsor";
    case Method::NRMGS: return "nrmgs";
    case Method::NRMJ: return "nrmj";
    case Method::MMS: return "mms";
    case Method::TwoSweep: return "two_sweep";
    case Method::Newton: return "newton";
  }
  return "?";
}

/// True for the stationary members (Method 3.1 with a splitting: nrmicp::Solver); the Newton
/// member is nrmicp::Newton (newton.hpp).
inline bool is_stationary(Method m) { return m != Method::Newton; }

/// True for the stationary members whose M is the AOR lower-triangular part (no factorization of Lm).
inline bool is_aor_type(Method m) { return is_stationary(m) && m != Method::NRM && m != Method::NRMM; }

inline const char* to_string(ZUpdate z) {
  switch (z) {
    case ZUpdate::Auto: return "auto";
    case ZUpdate::Explicit: return "explicit";
    case ZUpdate::Solve: return "solve";
  }
  return "?";
}

inline const char* to_string(Inner k) {
  switch (k) {
    case Inner::Auto: return "auto";
    case Inner::Cholmod: return "cholmod";
    case Inner::Umfpack: return "umfpack";
    case Inner::EigenLLT: return "eigen_llt";
    case Inner::EigenLU: return "eigen_lu";
    case Inner::CG: return "cg";
  }
  return "?";
}

inline const char* to_string(Accelerate a) {
  switch (a) {
    case Accelerate::None: return "none";
    case Accelerate::Anderson: return "anderson";
  }
  return "?";
}

/// Every value of each option enum, in declaration order (the Python bindings list these).
inline constexpr Method all_methods[] = {Method::NRM,   Method::NRMM, Method::NRMAOR, Method::NRMSOR,
                                         Method::NRMGS, Method::NRMJ, Method::MMS,    Method::TwoSweep,
                                         Method::Newton};
/// The methods of nrmicp::Solver: all_methods but the Newton member's (the last).
inline constexpr auto stationary_methods = [] {
  std::array<Method, std::size(all_methods) - 1> out{};
  for (std::size_t i = 0; i < out.size(); ++i) out[i] = all_methods[i];
  return out;
}();
inline constexpr ZUpdate all_z_updates[] = {ZUpdate::Auto, ZUpdate::Explicit, ZUpdate::Solve};
inline constexpr Inner all_inners[] = {Inner::Auto, Inner::Cholmod, Inner::Umfpack, Inner::EigenLLT, Inner::EigenLU,
                                       Inner::CG};
inline constexpr Accelerate all_accelerations[] = {Accelerate::None, Accelerate::Anderson};

/// The z-update a solve uses. Auto = Explicit: measured faster (no solve with A: 4-10x on ICPs
/// at equal iteration counts) and more robust (it converged on unshifted-Laplacian and
/// thermoforming ICPs where Solve stagnated). Except the paper's NRM (Ω2 = I, far from diag A)
/// on an ICP (ζ not constant): there Explicit stagnated on Bai's ICPs and Solve converged (~145
/// iterations). Solve is also needed when ζ's Lipschitz constant is about 1 (README). MMS is the
/// Zheng–Vong baseline, whose definition includes the Solve update: Auto keeps it on an ICP
/// (else it equals NRMGS).
inline ZUpdate resolve_z_update(ZUpdate asked, Method method, bool omega2_given, bool icp) {
  if (asked != ZUpdate::Auto) return asked;
  const bool paper_update = icp && ((method == Method::NRM && !omega2_given) || method == Method::MMS);
  return paper_update ? ZUpdate::Solve : ZUpdate::Explicit;
}

}  // namespace nrmicp
