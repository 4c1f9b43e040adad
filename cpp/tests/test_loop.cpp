// The iteration loop: per-solve options, the stopping rules, and Res at extreme scales.
#include "common.hpp"

#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <vector>

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

TEST_CASE("the progress hook: silent at verbose = 0; first iterate and final status at verbose > 0") {
  BaiLcp P;
  std::vector<int> ks;
  std::vector<std::string> messages;
  const Solver<RowMat>::Progress hook = [&](int k, double res, double best, double, const std::string& message) {
    CHECK(best <= res);
    ks.push_back(k);
    messages.push_back(message);
  };
  Options o;
  const Result quiet = Solver<RowMat>(P.A, o).solve(P.q, Zeta<int>::none(), nullptr, {}, {}, &o, hook);
  CHECK(ks.empty());
  o.verbose = 1;
  const Result r = Solver<RowMat>(P.A, o).solve(P.q, Zeta<int>::none(), nullptr, {}, {}, &o, hook);
  REQUIRE(ks.size() >= 2);
  CHECK(ks.front() == 0);
  CHECK(messages.front().empty());
  CHECK(ks.back() == r.iterations);
  CHECK(messages.back() == r.message);
  CHECK(r.z == quiet.z);
}

namespace {
// A toy step for the shared loop: Res 1, 1/2, 1/3, ...; after `limit` moves it ends the solve itself.
struct EndingStep : detail::StepBase {
  int moves = 0, limit = 3;
  std::optional<detail::StepEnd> finished;
  double evaluate(detail::Iterate& s) {
    s.step = 1.0;
    return 1.0 / (moves + 1);
  }
  void move_x(detail::Iterate&) {
    if (++moves == limit) finished = detail::StepEnd{Status::Stagnated, "ended by the step"};
  }
  void update_z(detail::Iterate&) {}
  const detail::StepEnd* end() const { return finished ? &*finished : nullptr; }
};
}  // namespace

TEST_CASE("a step ends the shared loop with its own status and message (step.end())") {
  Options o;
  o.tol = 1e-3;  // without the step's end the loop would run to iterate 1000
  o.record_history = true;
  Result res;
  const detail::Callback callback;
  const detail::Poll poll;
  const detail::Progress progress;
  const Eigen::VectorXd shift;
  detail::Monitor monitor(o, callback, poll, progress, shift, res, 2);
  detail::Iterate s;
  s.x = Eigen::VectorXd::Ones(2);
  s.z = Eigen::VectorXd::Zero(2);
  EndingStep step;
  detail::loop(step, s, monitor);
  monitor.finish(Eigen::VectorXd::Zero(2));
  CHECK(step.moves == 3);
  CHECK(res.status == Status::Stagnated);
  CHECK(res.message == "ended by the step");
  CHECK(res.history_iteration == std::vector<int>{0, 1, 2});  // the Monitor saw every iterate before the end
  CHECK(res.residual == doctest::Approx(1.0 / 3));
}

TEST_CASE("Anderson acceleration cuts the iterations on a slow problem, with few rejected steps") {
  // The 1D Laplacian tridiag(-1, 2, -1), n = 32, half of it in contact: plain NRMGS is slow.
  const int n = 32;
  std::vector<Eigen::Triplet<double>> t;
  Eigen::VectorXd q(n);
  for (int i = 0; i < n; ++i) {
    t.emplace_back(i, i, 2.0);
    if (i > 0) t.emplace_back(i, i - 1, -1.0);
    if (i + 1 < n) t.emplace_back(i, i + 1, -1.0);
    q[i] = (i < n / 2 ? -1.0 : 0.5) / n;
  }
  RowMat A(n, n);
  A.setFromTriplets(t.begin(), t.end());
  Options o;
  o.method = Method::NRMGS;
  o.tol = 1e-10;
  o.maxiter = 20000;
  const Result plain = solve(A, q, Zeta<int>::none(), o);
  o.accelerate = Accelerate::Anderson;
  const Result fast = solve(A, q, Zeta<int>::none(), o);
  o.anderson_m = 1;  // anderson_m matters: a memory of one difference accelerates less
  const Result short_memory = solve(A, q, Zeta<int>::none(), o);
  MESSAGE("plain ", plain.iterations, ", Anderson ", fast.iterations, " (m = 1: ", short_memory.iterations,
          "), rejected ", fast.counters.at("anderson_rejections"));  // measured: 2529, 132 (1166), 0
  REQUIRE(plain.status == Status::Converged);
  REQUIRE(fast.status == Status::Converged);
  CHECK((A * fast.z + q).cwiseMin(fast.z).norm() < 1e-10);  // Res recomputed here
  CHECK(10 * fast.iterations <= plain.iterations);
  CHECK(20 * fast.counters.at("anderson_rejections") <= fast.iterations);
  CHECK(short_memory.iterations > 2 * fast.iterations);
  CHECK(short_memory.iterations < plain.iterations);
}
