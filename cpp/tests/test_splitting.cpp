// Each method's splitting satisfies A = M − N, and the left matrix is Ω2 + (M + φ)Ω1.
#include "common.hpp"

#include <doctest/doctest.h>

using namespace nrmicp;

namespace {

Options options_for(Method m, Eigen::Index n) {
  Options o;
  o.method = m;
  if (m == Method::NRMAOR || m == Method::MMS || m == Method::TwoSweep) { o.alpha = 1.3; o.beta = 0.7; }
  if (m == Method::NRMSOR || m == Method::NRMM) o.alpha = 1.2;
  if (m != Method::MMS && m != Method::TwoSweep) {
    o.omega1 = Eigen::VectorXd::LinSpaced(n, 0.5, 1.5);
    o.phi = Eigen::VectorXd::LinSpaced(n, 0.0, 0.3);
  }
  return o;
}
}  // namespace

TEST_CASE("every splitting satisfies A = M - N") {
  const auto A = testing::bai(6, 4.0, false);
  for (Method m : stationary_methods) {
    CAPTURE(to_string(m));
    const auto o = options_for(m, A.rows());
    const auto p = resolve_parameters(A, o);
    const auto [M, N] = splitting_matrices(A, m, p);
    CHECK((testing::SpMat<>(M - N) - A).norm() < 1e-13 * A.norm());
  }
}

TEST_CASE("the left matrix is Omega2 + (M + phi) Omega1 and is triangular for AOR types") {
  const auto A = testing::bai(6, 4.0, false);
  const Eigen::Index n = A.rows();
  for (Method m : stationary_methods) {
    CAPTURE(to_string(m));
    const auto o = options_for(m, n);
    Solver<testing::SpMat<>> s(A, o);
    const auto& p = s.parameters();
    const auto [M, N] = splitting_matrices(A, m, p);
    const Eigen::MatrixXd expected = Eigen::MatrixXd(M) * p.omega1.asDiagonal() +
                                     Eigen::MatrixXd((p.omega2 + p.phi.cwiseProduct(p.omega1)).asDiagonal());
    const Eigen::MatrixXd Lm = Eigen::MatrixXd(s.splitting().left_matrix());
    CHECK((Lm - expected).norm() < 1e-12 * expected.norm());
    if (is_aor_type(m)) {
      CHECK(Lm.triangularView<Eigen::StrictlyUpper>().toDenseMatrix().norm() == 0.0);
      CHECK(s.splitting().kind() == (p.beta == 0 ? LeftKind::Diagonal : LeftKind::Lower));
    } else {
      CHECK(s.splitting().kind() == LeftKind::Factorized);
    }
  }
}

TEST_CASE("method defaults: NRM takes Omega2 = I, AOR types take Omega2 = diag(A)") {
  const auto A = testing::bai(4, 4.0, true);
  Options o;
  o.method = Method::NRM;
  CHECK(resolve_parameters(A, o).omega2.isApprox(Eigen::VectorXd::Ones(16)));
  o.method = Method::NRMGS;
  CHECK(resolve_parameters(A, o).omega2.isApprox(Eigen::VectorXd::Constant(16, 8.0)));
  o.method = Method::NRMJ;
  CHECK(resolve_parameters(A, o).beta == 0.0);
  o.method = Method::NRMM;
  CHECK(resolve_parameters(A, o).omega2.isApprox(Eigen::VectorXd::Constant(16, 8.0)));  // α = mean diag
}

TEST_CASE("a zero diagonal with the default Omega2 = diag(A) is a clear error") {
  auto A = testing::bai(3, 4.0, true);
  A.coeffRef(2, 2) = 0.0;
  Options o;
  o.method = Method::NRMGS;
  CHECK_THROWS_WITH_AS(resolve_parameters(A, o), doctest::Contains("omega2 = diag(A)"), std::invalid_argument);
}

TEST_CASE("the NRM left matrix switches to 64-bit indices when nnz(A) + n overflows the index type") {
  // The rule at its real threshold is tested in test_inner_solver.cpp; here the switch itself,
  // with the limit lowered so that a small problem crosses it.
  const auto A = testing::bai(5, 4.0, false);
  const Eigen::Index n = A.rows();
  for (Method m : {Method::NRM, Method::NRMM}) {
    CAPTURE(to_string(m));
    const auto p = resolve_parameters(A, options_for(m, n));
    const std::int64_t entries = A.nonZeros() + n;
    Splitting<int> narrow(A, m, p, Inner::Auto, entries);  // at the limit: fits
    Splitting<int> wide(A, m, p, Inner::Auto, entries - 1);
    CHECK_FALSE(narrow.wide_indices());
    CHECK(wide.wide_indices());
    CHECK((Eigen::MatrixXd(wide.left_matrix()) - Eigen::MatrixXd(narrow.left_matrix())).norm() == 0.0);
    Eigen::VectorXd r1 = Eigen::VectorXd::LinSpaced(n, -1.0, 1.0), r2 = r1, x1, x2;
    narrow.solve(r1, x1);
    wide.solve(r2, x2);
    CHECK((x1 - x2).norm() <= 1e-13 * x1.norm());
  }
}
