// The inner solver backends agree, and Auto picks CHOLMOD for SPD and UMFPACK otherwise.
#include "common.hpp"

#include <doctest/doctest.h>

#include <string>
#include <vector>

using namespace nrmicp;

namespace {
std::vector<Inner> available(bool spd) {
  std::vector<Inner> v{Inner::EigenLU};
  if (spd) v.push_back(Inner::EigenLLT);
  if (have_umfpack()) v.push_back(Inner::Umfpack);
  if (have_cholmod() && spd) v.push_back(Inner::Cholmod);
  return v;
}
}  // namespace

TEST_CASE("backends agree on symmetric positive definite and nonsymmetric matrices") {
  for (bool spd : {true, false}) {
    const auto A = testing::bai(15, 1.0, spd);
    const Eigen::VectorXd b = Eigen::VectorXd::LinSpaced(A.rows(), -1.0, 2.0);
    const Eigen::VectorXd x_ref = Eigen::MatrixXd(A).partialPivLu().solve(b);
    for (Inner k : available(spd)) {
      CAPTURE(InnerSolver<int>::name_of(k));
      InnerSolver<int> s;
      s.compute(A, k, "A");
      Eigen::VectorXd x;
      s.solve(b, x);
      CHECK((x - x_ref).norm() < 1e-12 * x_ref.norm());
    }
  }
}

TEST_CASE("auto picks Cholesky for SPD, LU otherwise, and LU for an indefinite symmetric matrix") {
  InnerSolver<int> s;
  s.compute(testing::bai(5, 4.0, true), Inner::Auto, "A");
  CHECK(std::string(s.name()) == (have_cholmod() ? "cholmod" : "eigen_llt"));
  s.compute(testing::bai(5, 4.0, false), Inner::Auto, "A");
  CHECK(std::string(s.name()) == (have_umfpack() ? "umfpack" : "eigen_lu"));
  s.compute(testing::bai(5, -4.5, true), Inner::Auto, "A");  // symmetric, positive diagonal, indefinite
  CHECK(std::string(s.name()) == (have_umfpack() ? "umfpack" : "eigen_lu"));
}

TEST_CASE("a singular matrix is a clear error") {
  testing::SpMat<> Z(4, 4);
  Z.insert(0, 0) = 1.0;
  InnerSolver<int> s;
  CHECK_THROWS_WITH_AS(s.compute(Z, Inner::Auto, "the test matrix"), doctest::Contains("the test matrix"),
                       std::runtime_error);
}
