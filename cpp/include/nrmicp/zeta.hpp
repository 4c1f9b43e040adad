// nrmicp — the implicit map ζ of ICP(q, A, ζ). Each kind costs only what it needs:
// None (an LCP) evaluates nothing, a constant is solved as the shifted LCP, an affine
// ζ(z) = Bz + c is one sparse product in C++, a functor is called once per iteration.
#pragma once

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "detail/box.hpp"
#include "options.hpp"

#include <algorithm>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>

namespace nrmicp {

enum class ZetaKind { None, Constant, Affine, Functor };
inline constexpr ZetaKind all_zeta_kinds[] = {ZetaKind::None, ZetaKind::Constant, ZetaKind::Affine, ZetaKind::Functor};
inline const char* to_string(ZetaKind k) {
  switch (k) {
    case ZetaKind::None: return "none";
    case ZetaKind::Constant: return "constant";
    case ZetaKind::Affine: return "affine";
    case ZetaKind::Functor: return "functor";
  }
  return "?";
}

template <typename StorageIndex = int>
class Zeta {
 public:
  using Vector = Eigen::VectorXd;
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  /// Writes ζ(z) to out (both of length n). Returns false when ζ cannot be evaluated.
  using Functor = std::function<bool(const double* z, double* out, Eigen::Index n)>;
  /// Writes a generalized Jacobian ∂ζ(z) (n-by-n) to J. Returns false when it cannot.
  using Jacobian = std::function<bool(const Vector& z, RowMatrix& J)>;
  /// The product of a matrix-free ∂ζ(z) at one z: writes ∂ζ(z)·v to out (both of length n).
  /// Returns false when it cannot.
  using Product = std::function<bool(const double* v, double* out, Eigen::Index n)>;
  /// A matrix-free Jacobian: ∂ζ at z as its product, called once per Newton step (the "linearize at
  /// z" call); the Product it returns is applied any number of times until the next call, and not
  /// after it. An empty Product: ∂ζ(z) cannot be had.
  using JacobianProduct = std::function<Product(const Vector& z)>;
  /// ∂ζ at one z as a Jacobian delivers it: the sparse matrix, or (matrix-free) only its product.
  struct Derivative {
    RowMatrix matrix;  ///< ∂ζ(z), n-by-n, when product is empty
    Product product;   ///< v ↦ ∂ζ(z)·v, for a matrix-free Jacobian
    bool matrix_free() const { return static_cast<bool>(product); }
  };
  /// A Jacobian that delivers either form, decided per call (the Python binding's: zeta_jacobian(z)
  /// returns a sparse matrix or a linear operator). Returns false when it cannot.
  using Differential = std::function<bool(const Vector& z, Derivative& d)>;

  /// ζ ≡ 0: the linear complementarity problem.
  static Zeta none() { return Zeta(ZetaKind::None); }
  /// ζ ≡ c: solved as LCP(q + Ac, A) in y = z − c.
  static Zeta constant(Vector c) { Zeta t(ZetaKind::Constant); t.c_ = std::move(c); return t; }
  /// ζ(z) = Bz + c.
  static Zeta affine(const RowMatrix& B, Vector c) {
    if (B.rows() != B.cols() || B.rows() != c.size())
      throw std::invalid_argument("Zeta::affine: B must be n-by-n and c of length n");
    Zeta t(ZetaKind::Affine); t.B_ = B; t.c_ = std::move(c); return t;   // one copy (SparseMatrix cannot move)
  }
  /// ζ given by a functor (e.g. a Python callable), optionally with its Jacobian (used by the
  /// Newton member for a semismooth Newton method on the whole ICP): a sparse ∂ζ(z) gives each step
  /// a sparse reduced system; a matrix-free one (JacobianProduct) a Krylov solve of the same system
  /// (detail/matrix_free.hpp); a Differential either, per call.
  static Zeta functor(Functor f, Jacobian jacobian = {}) {
    Differential d;
    if (jacobian)
      d = [j = std::move(jacobian)](const Vector& z, Derivative& out) { out.product = nullptr; return j(z, out.matrix); };
    return functor(std::move(f), std::move(d));
  }
  static Zeta functor(Functor f, JacobianProduct jacobian) {
    Differential d;
    if (jacobian)
      d = [j = std::move(jacobian)](const Vector& z, Derivative& out) { out.product = j(z); return out.matrix_free(); };
    return functor(std::move(f), std::move(d));
  }
  static Zeta functor(Functor f, Differential jacobian) {
    Zeta t(ZetaKind::Functor); t.f_ = std::move(f); t.j_ = std::move(jacobian); return t;
  }

  /// This ζ as the lower bound of z with the upper bound `u` (+∞ entries: no bound there; an empty
  /// u: none). Bounds — an upper one, or a constant ζ with −∞ entries (z free below there) — make the
  /// mixed complementarity problem: w ≥ 0 where z = ζ, w ≤ 0 where z = u, w = 0 between (PATH's).
  /// Every member solves it for ζ none or constant: the Newton member, and the modulus members in
  /// their box form (detail/modulus.hpp); an affine or functor ζ with u only the Newton member (its
  /// outer fixed point, without a Jacobian: check()).
  Zeta with_upper(Vector u) const { Zeta t = *this; t.upper_ = std::move(u); t.upper_map_.reset(); return t; }
  /// This ζ with the upper bound u(z) given as a map of the same four kinds: none (no upper bound),
  /// constant (as with_upper(c)), affine u(z) = Bz + c (evaluated in C++) or a functor (an implicit
  /// obstacle from above; +∞ entries: no bound on that row). An affine or functor u is implicit: the
  /// Newton member solves it by its outer fixed point, each outer step on the box frozen at its z
  /// (detail/outer_fixed_point.hpp); the modulus members refuse it (Solver::solve).
  Zeta with_upper(const Zeta& u) const {
    if (u.kind_ == ZetaKind::None) return with_upper(Vector());
    if (u.kind_ == ZetaKind::Constant) return with_upper(u.c_);
    Zeta t = *this;
    t.upper_.resize(0);
    t.upper_map_ = std::make_shared<const Zeta>(u);
    return t;
  }
  /// The constant upper bound (empty: none, or an implicit one: implicit_upper()).
  const Vector& upper() const { return upper_; }
  /// An upper bound that depends on z (affine or functor): eval_upper at each z.
  bool implicit_upper() const { return static_cast<bool>(upper_map_); }
  /// An upper bound (constant or implicit), or a constant ζ with a −∞ entry.
  bool bounded() const {
    return upper_.size() > 0 || implicit_upper() ||
           (kind_ == ZetaKind::Constant && (c_.array() == -std::numeric_limits<double>::infinity()).any());
  }
  /// out = u(z): the constant upper bound (empty: none), or the implicit one at z. False when u failed
  /// or gave NaN or −∞ somewhere (+∞ is no bound on that row).
  bool eval_upper(const Vector& z, Vector& out) const {
    if (!upper_map_) { out = upper_; return true; }
    if (!upper_map_->apply(z, out)) return false;
    return !(out.array().isNaN() || out.array() == -std::numeric_limits<double>::infinity()).any();
  }

  ZetaKind kind() const { return kind_; }
  const Vector& c() const { return c_; }
  const RowMatrix& B() const { return B_; }
  bool has_jacobian() const { return static_cast<bool>(j_); }
  /// ∂ζ(z) in the form the Jacobian delivers it (functor with a Jacobian only); false when it
  /// failed or a matrix has the wrong shape.
  bool derivative(const Vector& z, Derivative& d) const {
    return j_(z, d) && (d.matrix_free() || (d.matrix.rows() == z.size() && d.matrix.cols() == z.size()));
  }

  /// Checks the sizes against n; throws std::invalid_argument naming the mismatch.
  void check(Eigen::Index n) const {
    check_map(n, "Zeta");
    if (upper_map_) upper_map_->check_map(n, "Zeta: upper");
    if (bounded()) check_bounds(n);
  }

  /// out = ζ(z). Returns false when ζ failed or produced non-finite values.
  bool eval(const Vector& z, Vector& out) const {
    if (!apply(z, out)) return false;
    return kind_ == ZetaKind::None || kind_ == ZetaKind::Constant || out.allFinite();
  }

 private:
  explicit Zeta(ZetaKind k) : kind_(k) {}
  /// out = the map at z, unchecked (eval: ζ's rule, eval_upper: u's); false when the functor failed.
  bool apply(const Vector& z, Vector& out) const {
    switch (kind_) {
      case ZetaKind::None: out.setZero(z.size()); return true;
      case ZetaKind::Constant: out = c_; return true;
      case ZetaKind::Affine: out.noalias() = B_ * z; out += c_; return true;
      case ZetaKind::Functor: out.resize(z.size()); return f_(z.data(), out.data(), z.size());
    }
    return false;
  }
  /// The map's sizes against n (`what` names it in the message).
  void check_map(Eigen::Index n, const std::string& what) const {
    if ((kind_ == ZetaKind::Constant || kind_ == ZetaKind::Affine) && c_.size() != n)
      throw std::invalid_argument(what + ": c has length " + std::to_string(c_.size()) + ", expected n = " + std::to_string(n));
    if (kind_ == ZetaKind::Affine && B_.rows() != n)
      throw std::invalid_argument(what + ": B has " + std::to_string(B_.rows()) + " rows, expected n = " + std::to_string(n));
    if (kind_ == ZetaKind::Functor && !f_) throw std::invalid_argument(what + ": empty functor");
  }
  void check_bounds(Eigen::Index n) const {
    if (kind_ == ZetaKind::Functor && j_)
      throw std::invalid_argument("Zeta: an upper bound with a Jacobian of zeta is not supported (the semismooth Newton "
                                  "step has no box); leave the Jacobian out");
    if (upper_map_ && upper_map_->j_)
      throw std::invalid_argument("Zeta: an implicit upper bound takes no Jacobian (the outer fixed point freezes it)");
    if (upper_.size() && upper_.size() != n)
      throw std::invalid_argument("Zeta: upper has length " + std::to_string(upper_.size()) + ", expected n = " +
                                  std::to_string(n));
    for (Eigen::Index i = 0; i < n; ++i) {
      const double l = kind_ == ZetaKind::Constant ? c_[i] : kind_ == ZetaKind::None ? 0.0 : -std::numeric_limits<double>::infinity();
      const double u = upper_.size() ? upper_[i] : std::numeric_limits<double>::infinity();
      if (!(l <= u) || l == std::numeric_limits<double>::infinity() || u == -std::numeric_limits<double>::infinity())
        throw std::invalid_argument("Zeta: the bounds need -inf <= lower <= upper <= inf, lower < inf, upper > -inf; at "
                                    "index " + std::to_string(i) + " lower = " + std::to_string(l) + ", upper = " +
                                    std::to_string(u));
    }
  }
  ZetaKind kind_;
  Vector upper_;
  std::shared_ptr<const Zeta> upper_map_;  // an implicit upper bound u(z) (affine or functor), or null
  Vector c_;
  RowMatrix B_;
  Functor f_;
  Differential j_;
};

/// Res at z = 0, ‖min(q, −ζ(0))‖₂ (bounded: bounded_residual): the reference of the relative tolerance (Options::rtol);
/// NaN when ζ(0) failed.
template <typename StorageIndex>
double residual_at_zero(const Eigen::VectorXd& q, const Zeta<StorageIndex>& zeta,
                        const detail::Comm& comm = detail::serial_comm()) {
  Eigen::VectorXd zeta0;
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(q.size());
  Eigen::VectorXd upper0;
  if (!comm.all(zeta.eval(zero, zeta0) && zeta.eval_upper(zero, upper0))) return std::numeric_limits<double>::quiet_NaN();
  return detail::bounded_residual(q, -zeta0, zero, upper0, comm);  // with bounds: ‖mid(−ζ(0), −u(0), q)‖
}

/// `o` with its relative tolerance resolved for this problem: tol = target(Res(0)), rtol = 0.
template <typename StorageIndex>
void resolve_tolerance(Options& o, const Eigen::VectorXd& q, const Zeta<StorageIndex>& zeta,
                       const detail::Comm& comm = detail::serial_comm()) {
  if (o.rtol > 0) o.tol = o.target(residual_at_zero(q, zeta, comm));
  o.rtol = 0;
}

namespace detail {
/// A solve's inputs against A's n rows (this process's): q's and x0's lengths, ζ's sizes (Zeta::check);
/// throws std::invalid_argument, its message starting with `who`.
template <typename StorageIndex>
void check_solve_input(const std::string& who, const Eigen::VectorXd& q, const Eigen::VectorXd* z0,
                       const Zeta<StorageIndex>& zeta, Eigen::Index n) {
  if (q.size() != n)
    throw std::invalid_argument(who + ": q has length " + std::to_string(q.size()) + ", expected n = " + std::to_string(n));
  if (z0 && z0->size() != n)
    throw std::invalid_argument(who + ": x0 has length " + std::to_string(z0->size()) + ", expected n = " + std::to_string(n));
  zeta.check(n);
}

/// ζ with the constant upper bound another process has, +∞ on this process's n rows, where this process has
/// none (empty: ζ as it is): the branches a solve takes on bounds are then the same on all (one reduction).
template <typename StorageIndex>
std::optional<Zeta<StorageIndex>> agree_upper(const Zeta<StorageIndex>& zeta, Eigen::Index n, const Comm& comm) {
  const bool elsewhere = comm.any(zeta.upper().size() > 0);
  if (!elsewhere || zeta.upper().size() || zeta.implicit_upper()) return std::nullopt;
  return zeta.with_upper(Eigen::VectorXd::Constant(n, std::numeric_limits<double>::infinity()));
}
}  // namespace detail

}  // namespace nrmicp
