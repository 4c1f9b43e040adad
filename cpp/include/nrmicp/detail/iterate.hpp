// nrmicp — what every step of Method 3.1 shares: the iterate (x, z, ζ(z)) and the problem it
// iterates on, with the operations all steps use (products, ζ, the z-update, Res, the start).
// With bounds the problem is the box problem in y = z − s and m(x) replaces |x| (detail/modulus.hpp).
// Over an engine whose processes own parts of the rows (detail/engine.hpp: the PETSc engine), the
// vectors hold this process's rows, the products are the engine's, and every Res, every flag a step
// or the Monitor decides on (ζ failed, z not finite) is reduced over the processes (detail/comm.hpp),
// so that every process takes the same decisions.
#pragma once

#include "../inner_solver.hpp"
#include "../options.hpp"
#include "../result.hpp"
#include "../splitting.hpp"
#include "../zeta.hpp"
#include "comm.hpp"
#include "engine.hpp"
#include "modulus.hpp"
#include "residual.hpp"
#include "timer.hpp"

#include <Eigen/SparseCore>

#include <cmath>
#include <limits>

namespace nrmicp::detail {

/// The state of Method 3.1 between two steps.
struct Iterate {
  using Vector = Eigen::VectorXd;
  Vector x;                  ///< the modulus vector x⁽ᵏ⁾ (the one-pass sweep moves it to x⁽ᵏ⁺¹⁾ while evaluating)
  Vector z;                  ///< z⁽ᵏ⁾
  Vector zeta_z;             ///< ζ(z⁽ᵏ⁾), set by a step's evaluate (zero for an LCP)
  Vector zeta_prev;          ///< ζ(z⁽ᵏ⁻¹⁾), read by the explicit z-update (zero for an LCP)
  double step = std::numeric_limits<double>::infinity();  ///< max|x⁽ᵏ⁺¹⁾ − x⁽ᵏ⁾| of the last step
  bool zeta_ok = true;       ///< false once ζ returned non-finite values
  bool finite = true;        ///< false once z became non-finite (ζ is then not called: the iteration diverged)
};

/// The problem ICP(q, A, ζ) with the resolved parameters and z-update, and the timers of this
/// solve. One per solve (it owns a work vector); the steps hold a reference to it.
template <typename MatrixType>
class Context {
 public:
  using StorageIndex = typename MatrixType::StorageIndex;
  using Vector = Eigen::VectorXd;

  Context(const MatrixType& A, const Vector& q, const Zeta<StorageIndex>& zeta, const Parameters& p, ZUpdate zu,
          const InnerSolver<StorageIndex>& a_solver, Timings& tm)
      : A(A), comm(comm_of(A)), q(q), zeta(zeta), p(p), zu(zu), tm(tm), a_solver_(a_solver) {}

  const MatrixType& A;
  const Comm& comm;  ///< the processes that own the other rows (serial_comm(): none)
  const Vector& q;
  const Zeta<StorageIndex>& zeta;
  const Parameters& p;
  double start_residual = std::numeric_limits<double>::infinity();  ///< Res(z0), set by start()
  const ZUpdate zu;  ///< Explicit or Solve (never Auto)
  Timings& tm;
  const BoxModulus* box = nullptr;  ///< the box of a bounded problem (ζ is then none), or null: the LCP's |x|

  Eigen::Index n() const { return A.rows(); }
  bool lcp() const { return zeta.kind() == ZetaKind::None; }

  void spmv(const Vector& v, Vector& out) const {
    ScopedTimer t(tm.spmv);
    multiply(A, v, out);
  }
  /// out = ζ(v); clears s.zeta_ok when ζ fails. Nothing to do for an LCP. ζ is never handed a
  /// non-finite v: that is the iteration's failure, not ζ's (s.finite is cleared instead).
  void eval_zeta(Iterate& s, const Vector& v, Vector& out) const {
    if (lcp()) return;
    if (!comm.all(v.allFinite())) {
      s.finite = false;
      return;
    }
    ScopedTimer t(tm.zeta);
    const bool ok = comm.all(zeta.eval(v, out));
    // A ζ evaluated here (Affine: finite B, c) overflowing at a finite v: the iterate ran away.
    if (!ok && zeta.kind() != ZetaKind::Functor) s.finite = false;
    else s.zeta_ok = ok;
  }
  /// out = ζ-part + Ω1(m(x) + x)/γ (no ζ-part when null): the explicit z-update, and ẑ.
  void from_modulus(const Vector* zeta_part, const Vector& x, Vector& out) const {
    with_modulus(box, [&](const auto& m) { from_modulus(m, zeta_part, x, out); });
  }
  /// out = m(x) (the two-sweep step's second sweep).
  void modulus(const Vector& x, Vector& out) const {
    out.resize(x.size());
    with_modulus(box, [&](const auto& m) {
      for (Eigen::Index i = 0; i < x.size(); ++i) out[i] = m.value(i, x[i]);
    });
  }
  /// z from x: explicit z = ζ(z⁽ᵏ⁻¹⁾) + Ω1(m(x) + x)/γ, or the paper's A z = Ω2(m(x) − x)/γ − q.
  void z_update(Iterate& s) {
    if (zu == ZUpdate::Explicit) {
      from_modulus(lcp() ? nullptr : &s.zeta_prev, s.x, s.z);
      return;
    }
    const Vector& om2 = p.omega2;
    work_.resize(n());
    with_modulus(box, [&](const auto& m) {
      for (Eigen::Index i = 0; i < n(); ++i) work_[i] = om2[i] * m.minus(i, s.x[i]) / p.gamma - q[i];
    });
    ScopedTimer t(tm.inner_solve);
    a_solver_.solve(work_, s.z);
  }
  /// After x moved to x⁽ᵏ⁺¹⁾: ζ(z⁽ᵏ⁾) becomes the explicit update's ζ-part, and z⁽ᵏ⁺¹⁾ is made.
  void next_z(Iterate& s) {
    if (!lcp()) s.zeta_prev.swap(s.zeta_z);
    z_update(s);
  }
  /// Res(z) = ‖min(Az + q, z − ζ(z))‖₂ of s.z from Az (ζ(z) in s.zeta_z for an ICP; a box's
  /// ‖mid(z − lo, z − hi, Az + q)‖₂ with bounds).
  double residual(const Vector& Az, const Iterate& s) {
    ResidualSum res;
    if (!lcp()) {
      for (Eigen::Index i = 0; i < n(); ++i) res.add(Az[i] + q[i], s.z[i] - s.zeta_z[i]);
    } else {
      with_modulus(box, [&](const auto& m) {
        for (Eigen::Index i = 0; i < n(); ++i) m.add(res, i, Az[i] + q[i], s.z[i]);
      });
    }
    return residual_norm(res, s);
  }
  /// Res from the sum of squares a pass accumulated for s.z (and s.zeta_z): its square root, or
  /// Res recomputed with a scaled norm when the plain sum overflowed or underflowed.
  double residual_norm(ResidualSum sum, const Iterate& s) {
    sum.sum = comm.sum(sum.sum);
    if (sum.plain_is_accurate()) return std::sqrt(sum.sum);
    Vector Az(n());
    spmv(s.z, Az);
    if (box) return box->box.residual(Az + q, s.z, comm);
    work_.resize(n());
    for (Eigen::Index i = 0; i < n(); ++i) work_[i] = std::min(Az[i] + q[i], lcp() ? s.z[i] : s.z[i] - s.zeta_z[i]);
    return comm.stable_norm(work_);
  }
  /// x⁽⁰⁾ = γ/2 (Ω1⁻¹(z0 − ζ(z0)) − Ω2⁻¹(Az0 + q)) (the inverse of x ↦ (z, w), with or without a
  /// box) and z⁽⁰⁾ from it; false when ζ(z0) failed
  /// (then s.z = z0). Res(z0) goes to start_residual (a candidate for the best iterate).
  bool start(const Vector* z0, Iterate& s) {
    s.zeta_z = Vector::Zero(n());
    s.zeta_prev = Vector::Zero(n());
    Vector zs = z0 ? *z0 : Vector::Zero(n());
    eval_zeta(s, zs, s.zeta_prev);
    if (!s.zeta_ok) {
      s.z = std::move(zs);
      return false;
    }
    Vector Az(n());
    spmv(zs, Az);
    Az += q;
    start_residual = box ? box->box.residual(Az, zs, comm) : comm.stable_norm(Az.cwiseMin(zs - s.zeta_prev));
    if (std::isnan(start_residual)) start_residual = std::numeric_limits<double>::infinity();
    s.x = p.gamma / 2 * ((zs - s.zeta_prev).cwiseQuotient(p.omega1) - Az.cwiseQuotient(p.omega2));
    s.z.resize(n());
    z_update(s);
    return true;
  }

 private:
  template <typename Modulus>
  void from_modulus(const Modulus& m, const Vector* zeta_part, const Vector& x, Vector& out) const {
    const Vector& om1 = p.omega1;
    const double gamma = p.gamma;
    const Eigen::Index n = x.size();
    if (zeta_part) {
      for (Eigen::Index i = 0; i < n; ++i) out[i] = (*zeta_part)[i] + m.in_box(i, om1[i] * m.plus(i, x[i]) / gamma);
    } else {
      for (Eigen::Index i = 0; i < n; ++i) out[i] = m.in_box(i, om1[i] * m.plus(i, x[i]) / gamma);
    }
  }

  const InnerSolver<StorageIndex>& a_solver_;
  Vector work_;
};

}  // namespace nrmicp::detail
