// The inner solver backends agree, and Auto picks CHOLMOD for SPD and UMFPACK otherwise.
#include "common.hpp"

#include <doctest/doctest.h>

#include <cstdint>
#include <limits>
#include <string>
#include <utility>
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

TEST_CASE("an empty matrix (a process without rows) factorizes to nothing, with every backend") {
  for (const Inner k : {Inner::Auto, Inner::Cholmod, Inner::Umfpack, Inner::EigenLLT, Inner::EigenLU}) {
    InnerSolver<int> s;
    s.compute(testing::SpMat<>(0, 0), k, "the empty block");
    CHECK(s.ready());
    Eigen::VectorXd x(3);
    s.solve(Eigen::VectorXd(0), x);
    CHECK(x.size() == 0);
  }
}

TEST_CASE("a singular matrix is a clear error") {
  testing::SpMat<> Z(4, 4);
  Z.insert(0, 0) = 1.0;
  InnerSolver<int> s;
  CHECK_THROWS_WITH_AS(s.compute(Z, Inner::Auto, "the test matrix"), doctest::Contains("the test matrix"),
                       std::runtime_error);
}

TEST_CASE("a symmetric matrix whose Cholesky pivot is a rounding error is singular, on every BLAS") {
  // [[2, 2], [2, 2]]: the last pivot 2 - (2/sqrt 2)^2 is +4e-16 or negative depending on the
  // kernel; either way the matrix is refused, by CHOLMOD (rcond) and then by the LU
  testing::SpMat<> S(2, 2);
  S.insert(0, 0) = 2.0; S.insert(0, 1) = 2.0; S.insert(1, 0) = 2.0; S.insert(1, 1) = 2.0;
  S.makeCompressed();
  InnerSolver<int> s;
  if (have_cholmod()) {  // (Eigen's SimplicialLLT has no such check)
    CHECK_THROWS_WITH_AS(s.compute(S, Inner::Auto, "the test matrix"), doctest::Contains("singular"),
                         std::runtime_error);
    CHECK_THROWS_WITH_AS(s.compute(S, Inner::Cholmod, "the test matrix"), doctest::Contains("singular"),
                         std::runtime_error);
  }
  S.coeffRef(1, 1) = 3.0;  // well conditioned: accepted
  CHECK_NOTHROW(s.compute(S, Inner::Auto, "the test matrix"));
}

TEST_CASE("a matrix with an empty row or column is rejected before any backend sees it") {
  // Eigen's SparseLU did not return on an all-zero matrix (n >= 21); CHOLMOD's analysis of it
  // left Eigen's wrapper a null factor.
  testing::SpMat<> Z(30, 30);
  testing::SpMat<> C = testing::bai(6, 4.0, true);
  C.prune([](Eigen::Index, Eigen::Index col, double) { return col != 7; });  // column 7 empty
  for (const auto* M : {&Z, &C}) {
    std::vector<Inner> kinds{Inner::Auto, Inner::EigenLU, Inner::EigenLLT};
    if (have_cholmod()) kinds.push_back(Inner::Cholmod);
    if (have_umfpack()) kinds.push_back(Inner::Umfpack);
    for (Inner k : kinds) {
      CAPTURE(InnerSolver<int>::name_of(k));
      InnerSolver<int> s;
      try {
        s.compute(*M, k, "the test matrix");
        FAIL("no exception");
      } catch (const FactorizationError& e) {
        CHECK(e.reason() == FactorizationError::Reason::Singular);
        CHECK(std::string(e.what()).find("the test matrix is singular") != std::string::npos);
      }
    }
  }
}

TEST_CASE("64-bit indices are needed exactly when the entries overflow the index type") {
  const std::int64_t max32 = std::numeric_limits<std::int32_t>::max();
  CHECK_FALSE(detail::needs_wide_indices<std::int32_t>(max32));
  CHECK(detail::needs_wide_indices<std::int32_t>(max32 + 1));
  CHECK_FALSE(detail::needs_wide_indices<std::int64_t>(max32 + 1));
}

#if defined(NRMICP_HAVE_CHOLMOD)
TEST_CASE("CHOLMOD failures are reported as what they are, not as 'singular'") {
  using R = FactorizationError::Reason;
  auto reason = [](int status, bool has_factor) {
    try {
      detail::check_cholmod<int>(status, has_factor, "M");
    } catch (const FactorizationError& e) {
      return std::make_pair(e.reason(), std::string(e.what()));
    }
    return std::make_pair(R::Singular, std::string("no exception"));
  };
  CHECK(reason(CHOLMOD_OUT_OF_MEMORY, true).first == R::OutOfMemory);
  const auto overflow = reason(CHOLMOD_TOO_LARGE, true);
  CHECK(overflow.first == R::IndexOverflow);
  CHECK(overflow.second.find("int64") != std::string::npos);
  CHECK(reason(CHOLMOD_OK, false).first == R::Failed);  // analysis made no factor
  CHECK_NOTHROW(detail::check_cholmod<int>(CHOLMOD_NOT_POSDEF, true, "M"));
}
#endif

#if defined(NRMICP_HAVE_UMFPACK)
TEST_CASE("UMFPACK out of memory is a memory error that points at 64-bit indices") {
  try {
    detail::check_umfpack<int>(UMFPACK_ERROR_out_of_memory, "M");
    FAIL("no exception");
  } catch (const FactorizationError& e) {
    CHECK(e.reason() == FactorizationError::Reason::OutOfMemory);
    CHECK(std::string(e.what()).find("int64") != std::string::npos);
  }
  CHECK_NOTHROW(detail::check_umfpack<int>(UMFPACK_WARNING_singular_matrix, "M"));
}
#endif

namespace {
/// A random sparse matrix with about `per_row` entries per row, some of them explicit zeros.
template <typename M>
M random_sparse(Eigen::Index rows, Eigen::Index cols, int per_row, unsigned seed) {
  std::vector<Eigen::Triplet<double>> t;
  std::uint64_t s = seed;
  auto next = [&s] { s = s * 6364136223846793005ull + 1442695040888963407ull; return s >> 33; };
  for (Eigen::Index i = 0; i < rows; ++i)
    for (int k = 0; k < per_row; ++k) {
      const double v = (next() % 5 == 0) ? 0.0 : static_cast<double>(next() % 1000) / 100.0 - 5.0;
      t.emplace_back(i, static_cast<Eigen::Index>(next() % static_cast<std::uint64_t>(cols)), v);
    }
  M A(rows, cols);
  A.setFromTriplets(t.begin(), t.end());
  A.makeCompressed();
  return A;
}
}  // namespace

TEST_CASE("the split sparse product (pattern once, values per step) equals Eigen's product") {
  using RowMat = testing::SpMat<int, Eigen::RowMajor>;
  using ColMat = testing::SpMat<int, Eigen::ColMajor>;
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const RowMat L = random_sparse<RowMat>(40, 30, 4, seed), R = random_sparse<RowMat>(30, 25, 3, seed + 100);
    const Eigen::MatrixXd expected = Eigen::MatrixXd(L) * Eigen::MatrixXd(R);
    RowMat C = detail::product(L, R);
    CHECK((Eigen::MatrixXd(C) - expected).cwiseAbs().maxCoeff() < 1e-12);
    // The pattern holds every structural product term, zeros included: new values on the same
    // patterns are recomputed in place.
    RowMat L2 = L;
    for (Eigen::Index p = 0; p < L2.nonZeros(); ++p) L2.valuePtr()[p] = 1.0 + 0.5 * static_cast<double>(p % 7);
    std::vector<int> position;
    REQUIRE(detail::product_values(L2, R, C, position));
    CHECK((Eigen::MatrixXd(C) - Eigen::MatrixXd(L2) * Eigen::MatrixXd(R)).cwiseAbs().maxCoeff() < 1e-12);
    // A column-major left factor gives the same result.
    CHECK((Eigen::MatrixXd(detail::product(ColMat(L), R)) - expected).cwiseAbs().maxCoeff() < 1e-12);
  }
  // A term outside C's pattern is refused, not dropped.
  RowMat L(2, 2), R(2, 2);
  L.insert(0, 0) = 1.0;
  R.insert(0, 0) = 2.0;
  L.makeCompressed();
  R.makeCompressed();
  RowMat C = detail::product(L, R);
  RowMat L3(2, 2);
  L3.insert(0, 1) = 1.0;
  L3.makeCompressed();
  RowMat R3(2, 2);
  R3.insert(1, 1) = 3.0;
  R3.makeCompressed();
  std::vector<int> position;
  CHECK_FALSE(detail::product_values(L3, R3, C, position));
}

TEST_CASE("is_symmetric reads the mirror of every entry, stored or not") {
  using ColMat = testing::SpMat<int, Eigen::ColMajor>;
  ColMat S = testing::bai<int, Eigen::ColMajor>(4, 4.0, true);
  S.makeCompressed();
  CHECK(detail::is_symmetric(S));
  CHECK_FALSE(detail::is_symmetric(testing::bai<int, Eigen::ColMajor>(4, 4.0, false)));
  ColMat T = S;
  T.coeffRef(0, 5) += 1e-3;  // a new entry whose mirror is not stored
  T.makeCompressed();
  CHECK_FALSE(detail::is_symmetric(T));
  ColMat U = S;
  U.coeffRef(1, 0) += 1e-20;  // below 1e-14 ‖S‖_F: symmetric to rounding
  U.makeCompressed();
  CHECK(detail::is_symmetric(U));
}
