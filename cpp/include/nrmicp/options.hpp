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
#include <type_traits>
#include <variant>

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
/// Each field's default is its initializer here; its range and one-line doc are its row of
/// option_table (below), which Options::check and the Python layer read.
struct SolveOptions {
  double tol = 1e-8;
  double rtol = 0.0;
  int maxiter = 10000;
  double theta = 1.0;
  ZUpdate z_update = ZUpdate::Auto;
  Accelerate accelerate = Accelerate::None;
  int anderson_m = 5;
  bool record_history = false;
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
  int verbose = 0;
};

/// Every option, with its default: the set-up's (the method and its splitting, the inner
/// solver) and the defaults of the per-solve ones (SolveOptions). Vectors left empty take the
/// method's default (docs/SPEC.md); a NaN alpha/beta takes the method's default too.
struct Options : SolveOptions {
  Method method = Method::NRMGS;
  Eigen::VectorXd omega1;
  Eigen::VectorXd omega2;
  double gamma = 1.0;
  Eigen::VectorXd phi;
  double alpha = std::numeric_limits<double>::quiet_NaN();
  double beta = std::numeric_limits<double>::quiet_NaN();
  Inner inner = Inner::Auto;

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

  /// Throws std::invalid_argument naming the offending field, its value and what is accepted:
  /// each option against its row of option_table, then the rules that tie options together; on a
  /// distributed engine (`serial_engine` false) also those it cannot apply (OptionSpec::distributed).
  void check(Eigen::Index n, bool serial_engine = true) const;

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

/// Every value of an option enum, by its type (the option table's choices).
inline constexpr const auto& enum_values(Method) { return all_methods; }
inline constexpr const auto& enum_values(ZUpdate) { return all_z_updates; }
inline constexpr const auto& enum_values(Inner) { return all_inners; }
inline constexpr const auto& enum_values(Accelerate) { return all_accelerations; }

// ---------------------------------------------------------------------------------------------
// The option table: one row per option of nrmicp.solve / nrmicp::Options, the one declaration of
// its name (the C++ field's and the Python keyword's), scope, range and one-line doc. The default
// is the field's initializer above. Options::check checks each field against its row; the Python
// layer reads the table (nrmicp._core.option_table(), python/nrmicp/_options.py) for its
// signatures' defaults, its docstrings' parameter lines and its type checks.

/// When an option is given: at set-up only (nrmicp.Solver(...); Options), per solve (a set-up
/// default that each solve may override; SolveOptions), or with each call only (Solver.solve).
enum class Scope { Setup, Solve, Call };

/// The values a number (or each entry of a diagonal) may take: between low and high, each bound
/// open or closed; `finite`: not ±inf; `normal`: a positive value is at least DBL_MIN (1/x
/// overflows below, and x·y loses its digits). `note` is said after the range in messages;
/// `exempt` names the values another option admits (tol = 0 with rtol > 0).
struct Range {
  double low = -std::numeric_limits<double>::infinity();
  double high = std::numeric_limits<double>::infinity();
  bool low_open = false;
  bool high_open = false;
  bool finite = false;
  bool normal = false;
  const char* note = nullptr;
  bool (*exempt)(const Options&) = nullptr;

  constexpr bool bounded() const {
    return low > -std::numeric_limits<double>::infinity() || high < std::numeric_limits<double>::infinity();
  }
  bool contains(double v) const {
    return (low_open ? v > low : v >= low) && (high_open ? v < high : v <= high) && (!finite || std::isfinite(v));
  }
};

namespace range {
constexpr Range none() { return Range{}; }
constexpr Range above(double low, bool finite = false) {
  Range r;
  r.low = low;
  r.low_open = true;
  r.finite = finite;
  return r;
}
constexpr Range at_least(double low, bool finite = false) {
  Range r = above(low, finite);
  r.low_open = false;
  return r;
}
constexpr Range between(double low, double high, bool low_open, bool high_open) {
  Range r = above(low);
  r.low_open = low_open;
  r.high = high;
  r.high_open = high_open;
  return r;
}
constexpr Range normal(Range r) {
  r.normal = true;
  return r;
}
constexpr Range noted(Range r, const char* note, bool (*exempt)(const Options&) = nullptr) {
  r.note = note;
  r.exempt = exempt;
  return r;
}
}  // namespace range

/// Which members take an option on a distributed engine (nrmicp/petsc/): every member, the stationary
/// members only, the Newton member only, or none (OptionSpec::distributed; its reason, distributed_why).
enum class Distributed { Every, Stationary, Newton, Neither };

/// The Options member an option sets; none for the Python layer's own options.
using OptionField = std::variant<std::monostate, double Options::*, int Options::*, bool Options::*,
                                 Method Options::*, ZUpdate Options::*, Inner Options::*, Accelerate Options::*,
                                 Eigen::VectorXd Options::*>;

struct OptionSpec {
  const char* name;
  OptionField field;
  Scope scope;
  Range range;
  const char* doc;                         ///< one line
  const char* python_default = nullptr;    ///< as Python writes it, where it is not the field's default
  const char* python_type = nullptr;       ///< the type of an option without field, as Python's docs write it
  bool python = true;                      ///< false: C++ only (nrmicp.solve has no such keyword)
  Distributed distributed = Distributed::Every;  ///< the members that take it on a distributed engine
  const char* distributed_why = nullptr;   ///< why the others cannot (said in the refusal)
};

namespace detail {
constexpr bool tol_zero_with_rtol(const Options& o) { return o.tol == 0 && o.rtol > 0; }
}  // namespace detail

// In the order of nrmicp.solve's keywords.
inline constexpr OptionSpec option_table[] = {
    {"method", &Options::method, Scope::Setup, range::none(),
     "the member of the family (paper §3), a baseline (§2) or the semismooth Newton member", "'auto'"},
    {"tol", &Options::tol, Scope::Solve,
     range::noted(range::above(0, true), "or 0 with rtol > 0", detail::tol_zero_with_rtol),
     "stop when Res(z) = ‖min(Az + q, z − ζ(z))‖₂ < max(tol, rtol · Res(0)) (scipy's atol)", "None"},
    {"rtol", &Options::rtol, Scope::Solve, range::between(0, 1, false, true),
     "relative tolerance: the target is max(tol, rtol · Res(0)), Res(0) the residual at z = 0", "None"},
    {"maxiter", &Options::maxiter, Scope::Solve, range::at_least(0),
     "at most this many x-updates (newton: Newton steps on the finest level)"},
    {"omega1", &Options::omega1, Scope::Setup, range::normal(range::above(0)),
     "Ω1, a positive diagonal (a scalar times I, or a length-n vector)"},
    {"omega2", &Options::omega2, Scope::Setup, range::normal(range::above(0)),
     "Ω2, a positive diagonal (a scalar times I, or a length-n vector)"},
    {"gamma", &Options::gamma, Scope::Setup, range::normal(range::above(0, true)),
     "γ, which only rescales the modulus variable x"},
    {"phi", &Options::phi, Scope::Setup, range::at_least(0),
     "the relaxation diagonal φ of Method 3.1 (stationary members)"},
    {"alpha", &Options::alpha, Scope::Setup, range::normal(range::above(0, true)),
     "AOR α (nrmaor, nrmsor); nrmm: Ω2 = αI"},
    {"beta", &Options::beta, Scope::Setup, range::at_least(0, true), "AOR β (nrmaor)"},
    {"theta", &Options::theta, Scope::Solve, range::between(0, 2, true, false),
     "relaxation of the two-sweep step (two_sweep only: the others need 1)"},
    {"z_update", &Options::z_update, Scope::Solve, range::none(),
     "how z is recovered from the modulus vector x (stationary members)"},
    {"inner", &Options::inner, Scope::Setup, range::none(),
     "how the linear systems are solved: a sparse factorization, or newton's multigrid-preconditioned Krylov",
     nullptr, nullptr, true, Distributed::Stationary,
     "the PETSc engine's reduced solves are its own: PETSc options -nrmicp_inner_..."},
    {"accelerate", &Options::accelerate, Scope::Solve, range::none(),
     "safeguarded Anderson acceleration of the fixed-point map (stationary members)"},
    {"anderson_m", &Options::anderson_m, Scope::Solve, range::between(1, 100, false, false),
     "Anderson memory (the number of past differences kept)"},
    {"x0", {}, Scope::Call, range::none(), "the initial guess for z (a warm start); zeros when None", "None",
     "array_like (n,)"},
    {"callback", {}, Scope::Call, range::none(),
     "called with every iterate, scipy's way; StopIteration or True stops the solve", "None", "callable"},
    {"record_history", &Options::record_history, Scope::Solve, range::none(),
     "keep (iteration, seconds, Res) of every iterate"},
    {"stall_iterations", &Options::stall_iterations, Scope::Solve, range::at_least(1),
     "the window of the no-progress rules (STAGNATED)"},
    {"scale", {}, Scope::Setup, range::none(), "diagonal equilibration of badly scaled problems", "False",
     "False, True, 'rows' or 'both'", true, Distributed::Neither, "the default rule's units scaling is the one scaling here"},
    {"verbose", &Options::verbose, Scope::Solve,
     range::noted(range::at_least(0), "seconds between progress lines; 0: silent"),
     "a progress line every this many seconds (0: silent)"},
    {"hierarchy", {}, Scope::Setup, range::none(), "the nested iteration of method 'newton'", "'auto'",
     "'auto', 'amg', list of sparse matrices, or None"},
    {"components", {}, Scope::Setup, range::none(),
     "the components of a vector problem's unknowns, for the 'amg' hierarchy (each coarsened by itself)", "None",
     "None, int or array_like of int (n,)", true, Distributed::Neither,
     "BoomerAMG builds the hierarchy: PETSc options -nrmicp_hierarchy_pc_hypre_boomeramg_..."},
    {"polish", {}, Scope::Setup, range::none(), "Newton steps on the answer's active set after the method stops",
     "False", "bool", true, Distributed::Newton, "polishing is a Newton step: use method 'newton'"},
    {"zeta_jacobian", {}, Scope::Call, range::none(),
     "a generalized Jacobian of a callable ζ, for method 'newton' on the whole ICP", "None", "callable"},
    {"divergence_factor", &Options::divergence_factor, Scope::Solve, range::above(1),
     "DIVERGED when Res exceeds this factor times the best Res seen", nullptr, nullptr, false},
};

namespace detail {

/// A number for a message: an int field's as an integer, a double's as to_text.
inline std::string option_value_text(double v, bool integer) {
  return integer ? std::to_string(static_cast<long long>(v)) : to_text(v);
}

/// "must lie in [0, 1)", "must be a finite number > 0", "must be >= 1": what `r` accepts.
inline std::string range_text(const Range& r, bool integer) {
  if (r.high < std::numeric_limits<double>::infinity())
    return std::string("must lie in ") + (r.low_open ? "(" : "[") + option_value_text(r.low, integer) + ", " +
           option_value_text(r.high, integer) + (r.high_open ? ")" : "]");
  return std::string("must be ") + (r.finite ? "a finite number " : "") + (r.low_open ? "> " : ">= ") +
         option_value_text(r.low, integer);
}

/// A number option against its row: NaN passes where the default is NaN (the method's default).
inline void check_number(const OptionSpec& spec, double v, double default_value, bool integer, const Options& o) {
  const Range& r = spec.range;
  if (!r.bounded() || (std::isnan(v) && std::isnan(default_value)) || (r.exempt && r.exempt(o))) return;
  const auto name = [&] { return std::string("Options: ") + spec.name; };
  if (!r.contains(v))
    throw std::invalid_argument(name() + " " + range_text(r, integer) +
                                (r.note ? std::string(" (") + r.note + ")" : "") + ", got " +
                                option_value_text(v, integer));
  if (r.normal && v < DBL_MIN)
    throw std::invalid_argument(name() + " = " + to_text(v) + " is subnormal; it must be >= " +
                                to_text(DBL_MIN));
}

/// A diagonal option (empty: the method's default) against its row, entry by entry.
inline void check_diagonal(const OptionSpec& spec, const Eigen::VectorXd& v, Eigen::Index n) {
  if (v.size() == 0) return;
  const std::string name = std::string("Options: ") + spec.name;
  if (v.size() != n)
    throw std::invalid_argument(name + " must have length n = " + std::to_string(n) + ", got " +
                                std::to_string(v.size()));
  // (locals, not the row's fields, in the loop: it runs as fast as a loop over two constants)
  const bool open = spec.range.low_open, normal = spec.range.normal;
  const double low = spec.range.low;
  auto at = [&](Eigen::Index i) { return name + "[" + std::to_string(i) + "] = " + to_text(v[i]); };
  for (Eigen::Index i = 0; i < n; ++i) {
    if (!std::isfinite(v[i]) || (open ? !(v[i] > low) : v[i] < low))
      throw std::invalid_argument(at(i) + "; it must be finite and " + (open ? "> " : ">= ") + to_text(low));
    if (normal && v[i] < DBL_MIN)  // 1/x overflows, and x·y loses its digits
      throw std::invalid_argument(at(i) + " is subnormal; it must be >= " + to_text(DBL_MIN) + " (rescale the problem)");
  }
}

/// The diagonals' rows bound them below only (check_diagonal reads no high bound).
constexpr bool diagonals_bounded_below_only() {
  for (const OptionSpec& spec : option_table)
    if (std::holds_alternative<Eigen::VectorXd Options::*>(spec.field) &&
        spec.range.high < std::numeric_limits<double>::infinity())
      return false;
  return true;
}
static_assert(diagonals_bounded_below_only(), "check_diagonal reads a diagonal's low bound only");

/// One option of `o` against its row of option_table.
inline void check_option(const OptionSpec& spec, const Options& o, Eigen::Index n) {
  static const Options defaults;
  std::visit([&](auto field) {
    using F = decltype(field);
    if constexpr (std::is_same_v<F, double Options::*> || std::is_same_v<F, int Options::*>)
      check_number(spec, static_cast<double>(o.*field), static_cast<double>(defaults.*field),
                   std::is_same_v<F, int Options::*>, o);
    else if constexpr (std::is_same_v<F, Eigen::VectorXd Options::*>)
      check_diagonal(spec, o.*field, n);
  }, spec.field);
}

/// A row that a distributed engine refuses for some member says why (check_distributed's message).
constexpr bool distributed_refusals_say_why() {
  for (const OptionSpec& spec : option_table)
    if (spec.distributed != Distributed::Every && spec.distributed_why == nullptr) return false;
  return true;
}
static_assert(distributed_refusals_say_why(), "OptionSpec::distributed_why is missing");

/// Whether `method` takes the option of row `spec` on a distributed engine.
inline bool distributed_takes(const OptionSpec& spec, Method method) {
  const bool newton = method == Method::Newton;
  return spec.distributed == Distributed::Every || spec.distributed == (newton ? Distributed::Newton : Distributed::Stationary);
}

template <typename T>
bool same_value(const T& a, const T& b) {
  if constexpr (std::is_same_v<T, Eigen::VectorXd>) return a.size() == b.size() && a == b;
  else return a == b;
}

/// The options a distributed engine cannot apply to o.method refused, naming the first set away from its
/// default (the rows with an Options field: the Python layer checks its own rows).
inline void check_distributed(const Options& o) {
  static const Options defaults;
  for (const OptionSpec& spec : option_table)
    std::visit([&](auto field) {
      if constexpr (!std::is_same_v<decltype(field), std::monostate>)
        if (!distributed_takes(spec, o.method) && !same_value(o.*field, defaults.*field))
          throw std::invalid_argument(std::string("Options: ") + spec.name + " cannot apply to method '" +
                                      to_string(o.method) + "' on a distributed engine (" + spec.distributed_why + ")");
    }, spec.field);
}

}  // namespace detail

inline void Options::check(Eigen::Index n, bool serial_engine) const {
  auto fail = [](const std::string& msg) { throw std::invalid_argument("Options: " + msg); };
  // A row whose range another option relaxes (tol by rtol) comes after the others: that one is valid.
  for (const bool relaxed : {false, true})
    for (const OptionSpec& spec : option_table)
      if ((spec.range.exempt != nullptr) == relaxed) detail::check_option(spec, *this, n);
  if (theta != 1 && method != Method::TwoSweep)
    fail("theta is the relaxation of method 'two_sweep'; method '" + std::string(to_string(method)) +
         "' has none (got theta = " + to_text(theta) + ")");
  if ((method == Method::MMS || method == Method::TwoSweep) && (omega1.size() || phi.size()))
    fail("method '" + std::string(to_string(method)) + "' fixes omega1 = I and phi = 0; use an NRM-family "
         "method to set them");
  if (method == Method::Newton) check_newton(fail);
  if (!serial_engine) detail::check_distributed(*this);
}

/// The z-update a solve uses. Auto = Explicit (no solve with A: faster, and more robust on ICPs),
/// except the paper's NRM (Ω2 = I, far from diag A) on an ICP, where only Solve converges, and MMS,
/// the Zheng–Vong baseline whose definition includes Solve (docs/MEASUREMENTS.md, "The z-update 'auto'").
inline ZUpdate resolve_z_update(ZUpdate asked, Method method, bool omega2_given, bool icp) {
  if (asked != ZUpdate::Auto) return asked;
  const bool paper_update = icp && ((method == Method::NRM && !omega2_given) || method == Method::MMS);
  return paper_update ? ZUpdate::Solve : ZUpdate::Explicit;
}

}  // namespace nrmicp
