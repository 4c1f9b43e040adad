// Features of the headers no other C++ test reaches: Newton with a ζ Jacobian (semismooth),
// polish, the stall rules, and the interrupt poll.
#include "common.hpp"

#include <doctest/doctest.h>

#include <cmath>
#include <stdexcept>

using namespace nrmicp;

namespace {
using RowMat = testing::SpMat<int, Eigen::RowMajor>;
using Vec = Eigen::VectorXd;

/// ICP with ζ(z) = 0.1 sin z + s on Bai's nonsymmetric matrix, with the known solution z*.
struct SinIcp {
  RowMat A = testing::bai<int, Eigen::RowMajor>(10, 4.0, false);
  Vec z_star, s, q;
  SinIcp() {
    const auto k = testing::known_solution(A.rows());
    z_star = k.g + Vec::Constant(A.rows(), 0.5);
    s = z_star - k.g - 0.1 * z_star.array().sin().matrix();
    q = k.w - A * z_star;
  }
  Vec zeta(const Vec& z) const { return (0.1 * z.array().sin()).matrix() + s; }
  double res(const Vec& z) const { return (A * z + q).cwiseMin(z - zeta(z)).norm(); }
};

struct UserAbort : std::runtime_error {
  UserAbort() : std::runtime_error("user abort") {}
};
}  // namespace

TEST_CASE("Newton with a zeta Jacobian: semismooth Newton on the whole ICP") {
  const SinIcp p;
  int jacobian_calls = 0;
  const auto f = [&](const double* z, double* out, Eigen::Index n) {
    for (Eigen::Index i = 0; i < n; ++i) out[i] = 0.1 * std::sin(z[i]) + p.s[i];
    return true;
  };
  const auto jacobian = [&](const Vec& z, Zeta<int>::RowMatrix& J) {
    ++jacobian_calls;
    J.resize(z.size(), z.size());
    J.setIdentity();
    for (Eigen::Index i = 0; i < z.size(); ++i) J.coeffRef(i, i) = 0.1 * std::cos(z[i]);
    return true;
  };
  Options o;
  o.tol = 1e-11;
  const Newton<RowMat> newton(p.A, o);
  const Result with = newton.solve(p.q, Zeta<int>::functor(f, jacobian));
  const Result without = newton.solve(p.q, Zeta<int>::functor(f));
  REQUIRE(with.status == Status::Converged);
  REQUIRE(without.status == Status::Converged);
  CHECK(jacobian_calls > 0);  // the Jacobian path was taken
  CHECK(p.res(with.z) < 1e-11);
  CHECK((with.z - p.z_star).lpNorm<Eigen::Infinity>() < 1e-10);
  CHECK(jacobian_calls <= 4);                    // a few Newton steps (measured 3)
  CHECK(with.newton.outer_iterations <= jacobian_calls);  // each placed by one outer step
  CHECK(without.newton.outer_iterations >= 2);   // the Jacobian-free path: the outer fixed point
}

TEST_CASE("Newton with a matrix-free zeta Jacobian: the answer of the sparse one, by FGMRES") {
  const SinIcp p;
  int linearizations = 0, products = 0;
  const auto f = [&](const double* z, double* out, Eigen::Index n) {
    for (Eigen::Index i = 0; i < n; ++i) out[i] = 0.1 * std::sin(z[i]) + p.s[i];
    return true;
  };
  const Zeta<int>::JacobianProduct jacobian = [&](const Vec& z) -> Zeta<int>::Product {
    ++linearizations;
    const Vec d = (0.1 * z.array().cos()).matrix();
    return [d, &products](const double* v, double* out, Eigen::Index n) {
      ++products;
      for (Eigen::Index i = 0; i < n; ++i) out[i] = d[i] * v[i];
      return true;
    };
  };
  Options o;
  o.tol = 1e-11;
  const Newton<RowMat> newton(p.A, o);
  const Result r = newton.solve(p.q, Zeta<int>::functor(f, jacobian));
  REQUIRE(r.status == Status::Converged);
  CHECK(p.res(r.z) < 1e-11);
  CHECK((r.z - p.z_star).lpNorm<Eigen::Infinity>() < 1e-10);
  CHECK(linearizations > 0);
  CHECK(products >= r.counters.at("matrix_free_iterations"));  // one product per FGMRES iteration, at least
  CHECK(r.counters.at("matrix_free_iterations") > 0);
  CHECK(r.newton.inner_iterations >= r.counters.at("matrix_free_iterations"));
}

TEST_CASE("a matrix-free Jacobian whose product fails fails the step, not the solve") {
  const SinIcp p;
  const auto f = [&](const double* z, double* out, Eigen::Index n) {
    for (Eigen::Index i = 0; i < n; ++i) out[i] = 0.1 * std::sin(z[i]) + p.s[i];
    return true;
  };
  const Zeta<int>::JacobianProduct failing = [](const Vec&) -> Zeta<int>::Product {
    return [](const double*, double*, Eigen::Index) { return false; };
  };
  Options o;
  o.tol = 1e-11;
  const Result r = Newton<RowMat>(p.A, o).solve(p.q, Zeta<int>::functor(f, failing));
  CHECK(std::isfinite(r.residual));
  CHECK(r.z.allFinite());
  CHECK(r.residual <= p.res(Vec::Zero(p.A.rows())));  // the best iterate, never worse than the start
}

TEST_CASE("restarted FGMRES solves a nonsymmetric system to its absolute target") {
  const RowMat A = testing::bai<int, Eigen::RowMajor>(8, 4.0, false);
  const Vec b = Vec::LinSpaced(A.rows(), -1.0, 2.0);
  detail::Gmres gmres(5, 200);  // a short restart, to go through restarts
  const Vec inv_diag = A.diagonal().cwiseInverse();
  Vec x = Vec::Zero(A.rows());
  const int k = gmres.solve([&](const Vec& v, Vec& out) { out = A * v; },
                            [&](const Vec& v, Vec& out) { out = inv_diag.cwiseProduct(v); }, b, x, 1e-10);
  CHECK(k > 5);
  CHECK(k < 200);
  CHECK((b - A * x).norm() <= 1e-9);  // the true residual, not only the recursive estimate
  CHECK(gmres.residual() <= 1e-10);
}

TEST_CASE("polish: one Newton step from an approximate solution gains orders of magnitude") {
  const SinIcp p;
  Options so;
  so.method = Method::NRMGS;
  so.tol = 1e-5;
  const auto zeta = Zeta<int>::functor([&](const double* z, double* out, Eigen::Index n) {
    for (Eigen::Index i = 0; i < n; ++i) out[i] = 0.1 * std::sin(z[i]) + p.s[i];
    return true;
  });
  const Result rough = solve(p.A, p.q, zeta, so);
  REQUIRE(rough.status == Status::Converged);
  const double before = p.res(rough.z);
  REQUIRE(before > 1e-9);
  const Newton<RowMat> newton(p.A, Options{});
  const Result polished = newton.polish(p.q, zeta, rough.z, 1e-9);
  CHECK(polished.status == Status::Converged);
  CHECK(p.res(polished.z) < 1e-9);
  CHECK(p.res(polished.z) < 1e-4 * before);  // measured: 1e-5 -> 7e-12
  CHECK(polished.residual == doctest::Approx(p.res(polished.z)).epsilon(1e-6));
  // From a point it cannot improve, polish returns that point.
  const Result again = newton.polish(p.q, zeta, p.z_star, 1e-300);
  CHECK(p.res(again.z) <= p.res(p.z_star));
}

TEST_CASE("the stall rule: STAGNATED after stall_iterations at the rounding floor, not before") {
  const RowMat A = testing::bai<int, Eigen::RowMajor>(10, 4.0, true);
  const auto k = testing::known_solution(A.rows());
  const Vec q = k.w - A * k.g;
  Options o;
  o.method = Method::NRMGS;
  o.tol = 1e-300;  // unreachable: only the stall rules end the solve
  o.maxiter = 100000;
  o.stall_iterations = 5;
  const Result short_window = solve(A, q, Zeta<int>::none(), o);
  o.stall_iterations = 200;
  const Result long_window = solve(A, q, Zeta<int>::none(), o);
  REQUIRE(short_window.status == Status::Stagnated);
  REQUIRE(long_window.status == Status::Stagnated);
  CHECK(long_window.iterations >= short_window.iterations + 150);
  CHECK(long_window.iterations < 2000);
  CHECK((short_window.z - k.g).lpNorm<Eigen::Infinity>() < 1e-12);  // the best iterate
  CHECK(short_window.residual < 1e-12);
}

TEST_CASE("the interrupt poll: a throwing poll ends a solve that would run for hours") {
  const RowMat A = testing::bai<int, Eigen::RowMajor>(40, 0.0, true);
  const Vec q = Vec::Constant(A.rows(), -1.0);
  Options o;
  o.method = Method::NRMJ;
  o.tol = 1e-300;
  o.maxiter = 1000000000;
  o.stall_iterations = 1000000000;
  Solver<RowMat> s(A, o);
  int polls = 0;
  const auto poll = [&polls] {
    ++polls;
    throw UserAbort();
  };
  CHECK_THROWS_AS(s.solve(q, Zeta<int>::none(), nullptr, {}, poll), UserAbort);
  CHECK(polls == 1);
}
