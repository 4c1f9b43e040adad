// Every method solves problems with a known solution: LCP and ICP (affine, functor and
// constant ζ), both z-updates, int and int64 indices, row- and column-major matrices.
#include "common.hpp"

#include <doctest/doctest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <string>

using namespace nrmicp;

namespace {

Options tuned(Method m) {
  Options o;
  o.method = m;
  o.tol = 1e-10;
  if (m == Method::NRM) o.omega2 = Eigen::VectorXd();  // the paper's Ω2 = I: slower, still converges
  if (m == Method::NRMSOR) o.alpha = 1.1;
  return o;
}

template <typename Mat>
void check_solution(const Result& r, const Mat& A, const Eigen::VectorXd& q, const Eigen::VectorXd& zeta_z,
                    const Eigen::VectorXd& z_star, double tol) {
  CHECK(r.status == Status::Converged);
  const Eigen::VectorXd w = A * r.z + q;
  const Eigen::VectorXd g = r.z - zeta_z;
  CHECK(w.cwiseMin(g).norm() < tol);        // Res recomputed here
  CHECK(w.minCoeff() > -tol);
  CHECK(g.minCoeff() > -tol);
  CHECK(std::abs(g.dot(w)) < 1e-8);
  CHECK((r.z - z_star).lpNorm<Eigen::Infinity>() < 1e-8);
}

template <typename I, int Order>
void lcp_for_all_methods(bool symmetric) {
  const auto A = testing::bai<I, Order>(12, 4.0, symmetric);
  const auto k = testing::known_solution(A.rows());
  const Eigen::VectorXd q = k.w - A * k.g;  // ζ ≡ 0: z* = g*
  for (Method m : stationary_methods) {
    for (ZUpdate zu : {ZUpdate::Explicit, ZUpdate::Solve}) {
      CAPTURE(to_string(m));
      CAPTURE(static_cast<int>(zu));
      Options o = tuned(m);
      o.z_update = zu;
      Solver<testing::SpMat<I, Order>> s(A, o);
      const Result r = s.solve(q);
      check_solution(r, A, q, Eigen::VectorXd::Zero(A.rows()), k.g, o.tol);
    }
  }
}
}  // namespace

TEST_CASE("LCP: all methods, both z-updates, symmetric and nonsymmetric, int and int64, both storage orders") {
  lcp_for_all_methods<int, Eigen::ColMajor>(true);
  lcp_for_all_methods<int, Eigen::RowMajor>(false);
  lcp_for_all_methods<std::int64_t, Eigen::ColMajor>(false);
  lcp_for_all_methods<std::int64_t, Eigen::RowMajor>(true);
}

TEST_CASE("ICP with an affine zeta evaluated in C++") {
  const auto A = testing::bai(12, 4.0, false);
  const Eigen::Index n = A.rows();
  const auto k = testing::known_solution(n);
  // B = 0.2 * (shift by one), z* = g* + 1 so that ζ(z*) = B z* + c with c chosen below.
  testing::SpMat<int, Eigen::RowMajor> B(n, n);
  for (Eigen::Index i = 0; i + 1 < n; ++i) B.insert(i, i + 1) = 0.2;
  const Eigen::VectorXd z_star = k.g + Eigen::VectorXd::Ones(n);
  const Eigen::VectorXd c = z_star - k.g - B * z_star;
  const Eigen::VectorXd q = k.w - A * z_star;
  const auto zeta = Zeta<int>::affine(B, c);
  for (Method m : stationary_methods) {
    for (ZUpdate zu : {ZUpdate::Explicit, ZUpdate::Solve}) {
      CAPTURE(to_string(m));
      Options o = tuned(m);
      o.z_update = zu;
      const Result r = Solver<testing::SpMat<>>(A, o).solve(q, zeta);
      check_solution(r, A, q, Eigen::VectorXd(B * r.z + c), z_star, o.tol);
    }
  }
}

TEST_CASE("ICP with a functor zeta and with a constant obstacle") {
  const auto A = testing::bai(10, 4.0, true);
  const Eigen::Index n = A.rows();
  const auto k = testing::known_solution(n);
  const Eigen::VectorXd z_star = k.g + Eigen::VectorXd::Constant(n, 0.5);
  const Eigen::VectorXd s = z_star - k.g - 0.1 * z_star.array().sin().matrix();
  const Eigen::VectorXd q = k.w - A * z_star;
  int calls = 0;
  const auto zeta = Zeta<int>::functor([&](const double* z, double* out, Eigen::Index nn) {
    ++calls;
    for (Eigen::Index i = 0; i < nn; ++i) out[i] = 0.1 * std::sin(z[i]) + s[i];
    return true;
  });
  const Result r = Solver<testing::SpMat<>>(A, tuned(Method::NRMGS)).solve(q, zeta);
  check_solution(r, A, q, Eigen::VectorXd(0.1 * r.z.array().sin().matrix() + s), z_star, 1e-10);
  CHECK(calls == r.iterations + 2);  // once per iterate, once at the initial guess

  // ζ ≡ c: the shifted LCP, no functor involved.
  const Eigen::VectorXd c = z_star - k.g;
  const Result rc = Solver<testing::SpMat<>>(A, tuned(Method::NRMGS)).solve(q, Zeta<int>::constant(c));
  check_solution(rc, A, q, c, z_star, 1e-10);
}

TEST_CASE("the callback sees every iterate of the history, the converged one last") {
  const auto A = testing::bai(8, 4.0, true);
  const auto k = testing::known_solution(A.rows());
  const Eigen::VectorXd q = k.w - A * k.g;
  for (Method m : stationary_methods) {
    Options o = tuned(m);
    o.record_history = true;
    std::vector<int> ks;
    std::vector<double> rs;
    Eigen::VectorXd last;
    const Result r = Solver<testing::SpMat<>>(A, o).solve(q, Zeta<int>::none(), nullptr,
                                                          [&](int it, const Eigen::VectorXd& z, double res) {
                                                            ks.push_back(it);
                                                            rs.push_back(res);
                                                            last = z;
                                                            return false;
                                                          });
    CAPTURE(to_string(m));
    CHECK(r.status == Status::Converged);
    CHECK(ks == r.history_iteration);
    CHECK(rs == r.history_residual);
    CHECK(ks.back() == r.nit);
    CHECK(last == r.z);
    CHECK(rs.back() == r.residual);
  }
  // asking to stop at the iterate that converges does not change why the solve ended
  const Result first = Solver<testing::SpMat<>>(A, Options()).solve(q);
  const Result r = Solver<testing::SpMat<>>(A, Options()).solve(
      q, Zeta<int>::none(), nullptr, [&](int it, const Eigen::VectorXd&, double) { return it == first.nit; });
  CHECK(r.status == Status::Converged);
  CHECK(r.nit == first.nit);
}

TEST_CASE("statuses: max iterations, stagnation, callback stop, zeta failure; the best iterate is returned") {
  const auto A = testing::bai(8, 4.0, true);
  const auto k = testing::known_solution(A.rows());
  const Eigen::VectorXd q = k.w - A * k.g;
  Options o;
  o.maxiter = 3;
  o.record_history = true;
  Result r = Solver<testing::SpMat<>>(A, o).solve(q);
  CHECK(r.status == Status::MaxIterations);
  CHECK(r.history_residual.size() == 4);
  CHECK(r.residual == doctest::Approx(*std::min_element(r.history_residual.begin(), r.history_residual.end())));

  o = Options();
  o.tol = 1e-300;  // below what floating point can reach
  o.stall_iterations = 30;
  r = Solver<testing::SpMat<>>(A, o).solve(q);
  CHECK(r.status == Status::Stagnated);
  CHECK(r.residual < 1e-12);
  CHECK(r.z.allFinite());

  r = Solver<testing::SpMat<>>(A, Options()).solve(q, Zeta<int>::none(), nullptr,
                                                   [](int it, const Eigen::VectorXd&, double) { return it == 2; });
  CHECK(r.status == Status::CallbackStop);
  CHECK(r.iterations == 2);

  const auto bad = Zeta<int>::functor([](const double*, double* out, Eigen::Index nn) {
    for (Eigen::Index i = 0; i < nn; ++i) out[i] = NAN;
    return true;
  });
  r = Solver<testing::SpMat<>>(A, Options()).solve(q, bad);
  CHECK(r.status == Status::ZetaFailed);
}

TEST_CASE("warm start from the solution converges at once") {
  const auto A = testing::bai(8, 4.0, false);
  const auto k = testing::known_solution(A.rows());
  const Eigen::VectorXd q = k.w - A * k.g;
  Options o;
  o.tol = 1e-10;
  const Result r = Solver<testing::SpMat<>>(A, o).solve(q, Zeta<int>::none(), &k.g);
  CHECK(r.status == Status::Converged);
  CHECK(r.nit == 0);
}

TEST_CASE("Anderson acceleration converges to the same solution") {
  const auto A = testing::bai(12, 0.0, true);
  const auto k = testing::known_solution(A.rows());
  const Eigen::VectorXd q = k.w - A * k.g;
  Options o;
  o.tol = 1e-10;
  const Result plain = Solver<testing::SpMat<>>(A, o).solve(q);
  o.accelerate = Accelerate::Anderson;
  const Result aa = Solver<testing::SpMat<>>(A, o).solve(q);
  check_solution(aa, A, q, Eigen::VectorXd::Zero(A.rows()), k.g, o.tol);
  CHECK(plain.status == Status::Converged);
}

TEST_CASE("row-major A (the one-pass sweep): ICP and Anderson agree with the column-major generic loop") {
  // Row-major A takes detail/sweep.hpp for the AOR types; column-major takes the generic loop.
  const auto Ac = testing::bai<int, Eigen::ColMajor>(12, 0.0, false);
  const testing::SpMat<int, Eigen::RowMajor> Ar(Ac);
  const Eigen::Index n = Ac.rows();
  const auto k = testing::known_solution(n);
  const Eigen::VectorXd z_star = k.g + Eigen::VectorXd::Constant(n, 0.25);
  const Eigen::VectorXd s = z_star - k.g - 0.1 * z_star.array().sin().matrix();
  const Eigen::VectorXd q = k.w - Ac * z_star;
  const auto zeta = Zeta<int>::functor([&](const double* z, double* out, Eigen::Index nn) {
    for (Eigen::Index i = 0; i < nn; ++i) out[i] = 0.1 * std::sin(z[i]) + s[i];
    return true;
  });
  for (Method m : {Method::NRMGS, Method::NRMJ, Method::NRMAOR}) {
    for (Accelerate acc : {Accelerate::None, Accelerate::Anderson}) {
      CAPTURE(to_string(m));
      CAPTURE(static_cast<int>(acc));
      Options o;
      o.method = m;
      o.tol = 1e-10;
      o.accelerate = acc;
      o.z_update = ZUpdate::Explicit;
      if (m == Method::NRMAOR) { o.alpha = 1.1; o.beta = 0.9; }
      const Result rr = Solver<testing::SpMat<int, Eigen::RowMajor>>(Ar, o).solve(q, zeta);
      const Result rc = Solver<testing::SpMat<int, Eigen::ColMajor>>(Ac, o).solve(q, zeta);
      check_solution(rr, Ar, q, Eigen::VectorXd(0.1 * rr.z.array().sin().matrix() + s), z_star, o.tol);
      if (acc == Accelerate::None) CHECK(rr.nit == rc.nit);  // same arithmetic, same count
      CHECK((rr.z - rc.z).lpNorm<Eigen::Infinity>() < 1e-8);
    }
  }
}

namespace {
/// A box problem on Bai's matrix with a known solution: rows cycle through two-sided, lower only,
/// upper only, free and fixed bounds; z* sits at lower (w* > 0), at upper (w* < 0) or between (w* = 0).
struct KnownBox {
  Eigen::VectorXd lower, upper, z, w;
  explicit KnownBox(Eigen::Index n) : lower(n), upper(n), z(n), w(n) {
    constexpr double inf = std::numeric_limits<double>::infinity();
    for (Eigen::Index i = 0; i < n; ++i) {
      const double l = -0.5 + 0.25 * std::sin(double(i)), u = l + 1.0 + 0.5 * std::cos(double(i));
      const int kind = int(i % 5), place = int(i % 3);  // place: 0 at lower, 1 between, 2 at upper
      lower[i] = (kind == 2 || kind == 3) ? -inf : l;
      upper[i] = (kind == 1 || kind == 3) ? inf : kind == 4 ? l : u;
      const bool at_lower = place == 0 && std::isfinite(lower[i]), at_upper = place == 2 && std::isfinite(upper[i]);
      z[i] = kind == 4 || at_lower ? l : at_upper ? upper[i] : l + 0.3 * (u - l);
      w[i] = kind == 4 ? std::cos(3.0 * double(i)) : at_lower ? 0.75 : at_upper ? -0.75 : 0.0;
    }
  }
};

template <typename I, int Order>
void box_for_all_methods() {
  const auto A = testing::bai<I, Order>(8, 4.0, false);
  const KnownBox k(A.rows());
  const Eigen::VectorXd q = k.w - A * k.z;
  for (Method m : stationary_methods)
    for (ZUpdate zu : {ZUpdate::Explicit, ZUpdate::Solve}) {
      CAPTURE(std::string(to_string(m)));
      CAPTURE(static_cast<int>(zu));
      Options o = tuned(m);
      o.z_update = zu;
      // the explicit update's z is clamped to the box; the paper's solves A z = w − q: inside up to tol
      const double outside = zu == ZUpdate::Explicit ? 1e-15 : 1e-9;
      const Result r = Solver<testing::SpMat<I, Order>>(A, o).solve(q, Zeta<I>::constant(k.lower).with_upper(k.upper));
      CHECK(r.status == Status::Converged);
      CHECK((r.z - k.z).template lpNorm<Eigen::Infinity>() < 1e-8);
      const Eigen::VectorXd w = A * r.z + q;  // the MCP conditions, here
      for (Eigen::Index i = 0; i < A.rows(); ++i) {
        CHECK(r.z[i] >= k.lower[i] - outside);
        CHECK(r.z[i] <= k.upper[i] + outside);
        if (r.z[i] > k.lower[i] + 1e-8 && r.z[i] < k.upper[i] - 1e-8) CHECK(std::abs(w[i]) < 1e-8);
      }
    }
}
}  // namespace

TEST_CASE("bounds: every stationary member solves a box problem (free, upper-only, fixed rows), both storage orders") {
  box_for_all_methods<int, Eigen::RowMajor>();
  box_for_all_methods<int, Eigen::ColMajor>();
}
