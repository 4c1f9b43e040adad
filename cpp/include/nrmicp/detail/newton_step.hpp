// nrmicp — the plain Newton step of the Newton member on one level (docs/SPEC.md, "The Newton
// member"). With the inactive set ℐ = {x ≥ 0} of the current z (ActiveSetTest::active_set) it
// solves the piece of the modulus equation on which x lies,
//   (A z⁺ + q)_ℐ = 0,   (z⁺ − B z⁺)_𝒜 = c_𝒜         (detail/active_set.hpp)
// for ζ's linearization ζ(v) ≈ Bv + c at z. What changes between problems is the linearization
// (a policy type):
//   FixedLinearization     the (shifted) LCP (B = 0, c = 0) or an affine ζ = Bz + c: the same
//                          reduced system every step, analysed once
//   SemismoothLinearization  a callable ζ with its Jacobian J: B = J(z), c = ζ(z) − Jz, a new
//                          system each step (semismooth Newton on the whole ICP), sparse or
//                          matrix-free (detail/semismooth.hpp)
// The step only steps: the acceptance test, cycles, the fallback and the ends are the
// globalization's (detail::Globalized, detail/globalization.hpp).
#pragma once

#include "../result.hpp"
#include "../zeta.hpp"
#include "active_set.hpp"
#include "newton_level.hpp"
#include "timer.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <memory>
#include <type_traits>
#include <utility>
#include <vector>

namespace nrmicp::detail {

/// ζ ≡ 0 (the shifted LCP, B null) or ζ(z) = Bz + c, with the reduced system K analysed for it.
template <typename MatrixType>
struct FixedLinearization {
  using Level = NewtonLevel<MatrixType>;
  using Vector = Eigen::VectorXd;
  using System = typename Engine<MatrixType>::System;
  /// The active set alone fixes the step: a set seen before is a cycle, the last one a settled solve.
  static constexpr bool set_fixes_step = true;
  /// Its smoothing is a few projected sweeps (cheap: also after a step that met tol).
  static constexpr bool smoothing_solves = false;

  Level& level;
  System& K;
  const Vector& q;
  const typename Level::RowMatrix* B;
  const Vector* c;
  const Box* box = nullptr;  ///< the LCP's bounds lo ≤ z ≤ hi (detail/box.hpp; B null); null: z ≥ 0

  /// Res of v; Av + q in w, v − ζ(v) in g unless g_is_z (ζ(v) itself is not kept).
  double evaluate(const Vector& v, Vector& w, Vector& g, Vector&) const {
    return box ? level.evaluate(v, q, *box, w) : level.evaluate(v, q, B, c, w, g);
  }
  /// The LCP: g = z − ζ(z) is z itself, not stored (two n-vectors a level).
  bool g_is_z() const { return B == nullptr; }
  bool linearize(const Vector&, const Vector&) { return true; }  // nothing changes
  System& system() { return K; }
  /// The step's right-hand side: −q on the inactive rows, the bound (c, 0, or the box's) on the
  /// active ones; K has no active columns on the LCP's inactive rows, so a nonzero bound's part
  /// A_ℐ𝒜 z_𝒜 moves to their right-hand side (the box's upper bounds).
  void rhs(const std::vector<char>& set, Vector& b) const {
    bool bounded = false;
    for (Eigen::Index i = 0; i < b.size(); ++i) {
      const char s = set[i];
      b[i] = inactive_state(s) ? -q[i] : box ? box->bound(s, i) : c ? (*c)[i] : 0.0;
      bounded = bounded || (box && !inactive_state(s) && b[i] != 0);
    }
    if (!box || !level.comm().max(bounded ? 1.0 : 0.0)) return;  // (every process multiplies, or none)
    Vector t = Vector::Zero(b.size());
    for (Eigen::Index i = 0; i < b.size(); ++i)
      if (!inactive_state(set[i])) t[i] = b[i];
    ScopedTimer timer(level.timings().spmv);
    Vector At(b.size());
    multiply(level.matrix(), t, At);
    for (Eigen::Index i = 0; i < b.size(); ++i)
      if (inactive_state(set[i])) b[i] -= At[i];
  }
  Result sweep(const Vector& z0, int sweeps, double tol) {
    return box ? level.sweep(q, *box, z0, sweeps, tol) : level.sweep(q, B, c, z0, sweeps, tol);
  }
  /// Projected sweeps: on the LCP (B null) they keep z ≥ 0 (lo ≤ z ≤ hi), on the affine ICP z ≥ Bz + c.
  bool smoothable() const { return true; }
  void smooth(Vector& z, int sweeps) const {
    if (B) level.projected_gauss_seidel(q, *B, *c, z, sweeps);
    else level.projected_gauss_seidel(q, z, sweeps, box);
  }
};

/// Whether a linearization picks the active set of a step itself: predict_set(z, ζ(z), inactive)
/// (false: the test x ≥ 0 on z decides, as for every other policy).
template <typename L, typename = void>
struct predicts_set : std::false_type {};
template <typename L>
struct predicts_set<L, std::void_t<decltype(&L::predict_set)>> : std::true_type {};

/// The current iterate z (with w = Az + q, g = z − ζ(z), ζ(z), Res) and a trial step from it.
template <typename MatrixType, typename Linearization>
class NewtonStep {
 public:
  using Vector = Eigen::VectorXd;
  static constexpr bool set_fixes_step = Linearization::set_fixes_step;
  static constexpr bool smoothing_solves = Linearization::smoothing_solves;

  NewtonStep(NewtonLevel<MatrixType>& level, Linearization lin, Vector z)
      : level_(level), lin_(std::move(lin)), z_(std::move(z)) {
    const Eigen::Index n = level.size();
    w_.resize(n);
    z_new_.resize(n); w_new_.resize(n);
    if (!lin_.g_is_z()) { g_.resize(n); g_new_.resize(n); }
    if constexpr (!set_fixes_step) { zeta_z_.resize(n); zeta_new_.resize(n); }  // a fixed ζ keeps no ζ(z)
    r_ = lin_.evaluate(z_, w_, g_, zeta_z_);
  }

  Eigen::Index size() const { return z_.size(); }
  const Vector& z() const { return z_; }
  double residual() const { return r_; }
  int steps() const { return steps_; }
  int solves() const { return solves_; }
  long long inner_iterations() const { return inner_iterations_; }

  /// The inactive set ℐ = {x ≥ 0} of z, or the one the linearization predicts for z (a policy with
  /// predict_set: SemismoothLinearization's outer step).
  void active_set(std::vector<char>& inactive) {
    if constexpr (predicts_set<Linearization>::value)
      if (lin_.predict_set(z_, zeta_z_, inactive)) return;
    level_.test().active_set(w_, g(), inactive, lin_.box);
  }
  /// x ← x of z up to the factor γ/(2Ω1) (what the Monitor reads); ‖Δx‖∞ (∞ when x was empty).
  double modulus(Vector& x) const { return level_.test().modulus(w_, g(), x); }
  /// ζ's linearization at z; false when ζ's Jacobian failed.
  bool linearize() { return lin_.linearize(z_, zeta_z_); }
  /// How far ζ's Jacobian at z misses ζ's difference quotient (SemismoothLinearization::jacobian_miss).
  double jacobian_miss() { return lin_.jacobian_miss(z_, zeta_z_); }
  /// How far the last linearization moved z, relative to its size (SemismoothLinearization::move_ratio).
  double move_ratio() const { return lin_.move_ratio(z_); }
  /// The reduced system of the piece `inactive`; false when it is singular.
  bool factorize(const std::vector<char>& inactive) {
    ScopedTimer t(level_.timings().factorization);  // direct: numeric factorization; cg: the V-cycle's update
    return lin_.system().factorize(inactive);
  }

  /// The trial iterate z⁺ of the piece `inactive` (after factorize); its Res. The one inner solve
  /// of the Newton member: an iterative one (inner = cg) starts from z and stops at tol / 10, or
  /// at `forcing` × Res(z) if that is larger (inexact Newton; NewtonControl::forcing).
  double solve(const std::vector<char>& inactive, double tol, double forcing = 0, double settled_tol = 0) {
    Vector& rhs = w_new_;  // w⁺ is written after the solve: its storage holds the right-hand side
    lin_.rhs(inactive, rhs);
    z_new_ = z_;
    double target = std::max(0.1 * tol, forcing * r_);
    if (target == 0 && settled_tol > 0 && lin_.system().iterative())  // (NewtonControl::settled_tol)
      target = std::min(kKrylovRtol * level_.comm().stable_norm(rhs), 0.1 * settled_tol);
    {
      ScopedTimer t(level_.timings().inner_solve);
      inner_iterations_ += lin_.system().solve(rhs, z_new_, target);
    }
    ++solves_;
    ++steps_;
    return r_new_ = lin_.evaluate(z_new_, w_new_, g_new_, zeta_new_);
  }
  /// `sweeps` projected Gauss–Seidel sweeps on the trial z⁺ (FixedLinearization: ζ none, constant
  /// or affine); true when they changed its active set. Projected Gauss–Seidel is no contraction
  /// where A's diagonal does not dominate, so sweeps that raise Res are dropped: always for an affine
  /// ζ, on the LCP when they did not move the active set either (moving it is their purpose: the free
  /// boundary moves several layers a step); else a step exact on the right set is swept off it, every
  /// time (docs/MEASUREMENTS.md, "`Globalized::kSmoothingSweeps` = 2").
  bool smooth(int sweeps) {
    if (sweeps <= 0 || !lin_.smoothable()) return false;
    const Vector& g = lin_.g_is_z() ? z_new_ : g_new_;
    level_.test().active_set(w_new_, g, before_, lin_.box);
    const bool guarded = !lin_.g_is_z();
    const double r_plain = r_new_;
    unswept_ = z_new_;
    lin_.smooth(z_new_, sweeps);
    r_new_ = lin_.evaluate(z_new_, w_new_, g_new_, zeta_new_);
    const bool moved = !level_.test().has_active_set(w_new_, g, before_, lin_.box);
    // (on the LCP a rise within twice Res is rounding's, and dropping such sweeps cost steps: same section)
    if (guarded ? !(r_new_ < r_plain) : !moved && !(r_new_ <= 2 * r_plain)) {
      z_new_.swap(unswept_);
      r_new_ = lin_.evaluate(z_new_, w_new_, g_new_, zeta_new_);
      unswept_.resize(0);
      return false;
    }
    unswept_.resize(0);  // not held through the next step's solve (8 MB a million unknowns)
    return moved;
  }
  /// Res of the trial z⁺.
  double trial_residual() const { return r_new_; }
  /// The number of active points of the trial iterate z⁺ (after solve).
  std::size_t trial_active_count() const {
    return level_.test().active_count(w_new_, lin_.g_is_z() ? z_new_ : g_new_, lin_.box);
  }
  /// The trial iterate z⁺ moved back to z + alpha (z⁺ − z); its Res.
  double damp(double alpha) {
    z_new_ = z_ + alpha * (z_new_ - z_);
    return r_new_ = lin_.evaluate(z_new_, w_new_, g_new_, zeta_new_);
  }
  /// Whether the inner solve is iterative (a forcing loosens it; a direct solve is exact).
  bool iterative() { return lin_.system().iterative(); }
  /// The rounding level of Res at z (NewtonLevel::rounding_level).
  double rounding_level() const {
    return lin_.box ? level_.rounding_level(z_, lin_.q, *lin_.box, w_) : level_.rounding_level(z_, lin_.q, g(), w_);
  }
  /// The trial z⁺ did not move beyond rounding (only ties g ≈ w ≈ 0 changed sides).
  bool trial_still() const {
    const Comm& comm = level_.comm();
    return comm.inf_norm(z_new_ - z_) <= 1e-14 * comm.inf_norm(z_new_);
  }
  /// The active sets' bookkeeping over every process (NewtonLevel's).
  std::uint64_t fingerprint(const std::vector<char>& inactive) const { return level_.test().fingerprint(inactive); }
  bool same_set(const std::vector<char>& a, const std::vector<char>& b) const { return level_.test().same_set(a, b); }
  std::size_t active_count(const std::vector<char>& inactive) const { return level_.test().active_count(inactive); }
  const Comm& comm() const { return level_.comm(); }
  /// z ← the trial iterate.
  void accept() {
    z_.swap(z_new_); w_.swap(w_new_); g_.swap(g_new_); zeta_z_.swap(zeta_new_);
    r_ = r_new_;
  }
  /// z ← v (the fallback's iterate); its Res.
  double restart(const Vector& v) {
    z_new_ = v;
    r_new_ = lin_.evaluate(z_new_, w_new_, g_new_, zeta_new_);
    accept();
    return r_;
  }
  /// Sweeps of the fallback member on this problem from z0; its best iterate.
  Result sweep(const Vector& z0, int sweeps, double tol) { return lin_.sweep(z0, sweeps, tol); }

 private:
  /// g = z − ζ(z) of z.
  const Vector& g() const { return lin_.g_is_z() ? z_ : g_; }

  NewtonLevel<MatrixType>& level_;
  Linearization lin_;
  Vector z_, w_, g_, zeta_z_, z_new_, w_new_, g_new_, zeta_new_;
  std::vector<char> before_;  // the trial's active set before smooth()
  Vector unswept_;            // the trial before smooth(), while it decides (empty otherwise)
  double r_ = 0, r_new_ = 0;
  int steps_ = 0, solves_ = 0;
  long long inner_iterations_ = 0;
};

}  // namespace nrmicp::detail
