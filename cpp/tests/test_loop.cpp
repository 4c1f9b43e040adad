// The iteration loop: per-solve options, the stopping rules, and Res at extreme scales.
#include "common.hpp"

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <limits>

using namespace nrmicp;

namespace {
using RowMat = testing::SpMat<int, Eigen::RowMajor>;

struct BaiLcp {
  RowMat A = testing::bai<int, Eigen::RowMajor>(10, 4.0, true);
  Eigen::VectorXd q;
  BaiLcp() {
    const auto k = testing::known_solution(A.rows());
    q = k.w - A * k.g;
  }
};
}  // namespace

TEST_CASE("theta belongs to two_sweep: rejected for any other method, by name") {
  Options o;
  o.method = Method::NRMGS;
  o.theta = 0.5;
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("theta"), std::invalid_argument);
  o.method = Method::TwoSweep;
  CHECK_NOTHROW(o.check(3));
}

TEST_CASE("a per-solve theta is the theta the two-sweep iteration uses") {
  BaiLcp P;
  Options base;
  base.method = Method::TwoSweep;
  Options half = base;
  half.theta = 0.5;
  const Result set_up_half = Solver<RowMat>(P.A, half).solve(P.q);
  const Result set_up_one = Solver<RowMat>(P.A, base).solve(P.q);
  const Result per_solve_half = Solver<RowMat>(P.A, base).solve(P.q, Zeta<int>::none(), nullptr, {}, {}, &half);
  REQUIRE(set_up_half.iterations != set_up_one.iterations);  // theta matters on this problem
  CHECK(per_solve_half.iterations == set_up_half.iterations);
  CHECK(per_solve_half.z == set_up_half.z);
}

TEST_CASE("a per-solve theta is checked against the Solver's method") {
  BaiLcp P;
  Options it;
  it.theta = 0.5;  // it.method is ignored: the Solver's method (nrmgs) decides
  Solver<RowMat> s(P.A, Options());
  CHECK_THROWS_WITH_AS(s.solve(P.q, Zeta<int>::none(), nullptr, {}, {}, &it), doctest::Contains("theta"),
                       std::invalid_argument);
}

namespace {
// Issue 9 item 6: A = [-1], q = [1], ζ(z) = z + 1/2, nrmj, Ω2 = 2, the Solve update: Res stays
// exactly 1/2 while x triples every step.
struct Runaway {
  RowMat A{1, 1};
  Eigen::VectorXd q = Eigen::VectorXd::Ones(1);
  Options o;
  Runaway() {
    A.insert(0, 0) = -1.0;
    A.makeCompressed();
    o.method = Method::NRMJ;
    o.omega2 = Eigen::VectorXd::Constant(1, 2.0);
    o.z_update = ZUpdate::Solve;
    o.inner = Inner::EigenLU;
  }
};
}  // namespace

TEST_CASE("a runaway modulus vector is DIVERGED, with the best iterate") {
  Runaway P;
  const Result r = Solver<RowMat>(P.A, P.o).solve(P.q, Zeta<int>::functor([](const double* z, double* out, Eigen::Index n) {
    for (Eigen::Index i = 0; i < n; ++i) out[i] = z[i] + 0.5;
    return true;
  }));
  CHECK(r.status == Status::Diverged);
  CHECK(r.iterations < 100);
  CHECK(r.z.allFinite());
  CHECK(std::isfinite(r.residual));
}

TEST_CASE("zeta is never called on a non-finite iterate: that is divergence, not ZetaFailed") {
  Runaway P;
  P.o.divergence_factor = std::numeric_limits<double>::max();  // let x overflow
  bool saw_nonfinite = false;
  const Result r =
      Solver<RowMat>(P.A, P.o).solve(P.q, Zeta<int>::functor([&](const double* z, double* out, Eigen::Index n) {
        for (Eigen::Index i = 0; i < n; ++i) {
          saw_nonfinite |= !std::isfinite(z[i]);
          out[i] = z[i] + 0.5;
        }
        return true;
      }));
  CHECK(r.status == Status::Diverged);
  CHECK_FALSE(saw_nonfinite);
  CHECK(r.z.allFinite());
}

TEST_CASE("Res neither overflows nor underflows: a scaled problem iterates like the original") {
  // Scaling A and q by s (a power of two: exact) leaves the iterates unchanged; Res becomes
  // ‖min(s w, z)‖, whose squares overflow (s = 2^600) or underflow (s = 2^-600) in a plain sum.
  BaiLcp P;
  Options o;
  o.maxiter = 12;
  o.tol = 1e-300;
  o.stall_iterations = 1000;
  const Result ref = Solver<RowMat>(P.A, o).solve(P.q);
  for (double scale : {0x1p600, 0x1p-600}) {
    CAPTURE(scale);
    const RowMat As = scale * P.A;
    const Eigen::VectorXd qs = scale * P.q;
    const Result r = Solver<RowMat>(As, o).solve(qs);
    CHECK(r.nit == ref.nit);
    CHECK(r.z == ref.z);
    const Eigen::VectorXd m = (As * r.z + qs).cwiseMin(r.z);
    const double big = m.cwiseAbs().maxCoeff();
    CHECK(r.residual == doctest::Approx(big * (m / big).norm()).epsilon(1e-12));
    Options to_tol;
    to_tol.tol = 1e-8 * scale;
    const Result c = Solver<RowMat>(As, to_tol).solve(qs);
    CHECK(c.status == Status::Converged);
    CHECK(c.z.allFinite());
  }
}

TEST_CASE("subnormal parameters are rejected by name") {
  Options o;
  o.gamma = 1e-310;
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("gamma"), std::invalid_argument);
  o = Options();
  o.omega2 = Eigen::Vector3d(1, 1e-310, 1);
  CHECK_THROWS_WITH_AS(o.check(3), doctest::Contains("omega2[1]"), std::invalid_argument);
  BaiLcp P;
  const RowMat tiny = 1e-320 * P.A;
  CHECK_THROWS_WITH_AS(Solver<RowMat>(tiny, Options()), doctest::Contains("A[0,0]"), std::invalid_argument);
}
