// The Newton member: known solutions, complementarity, nested iteration with user-supplied
// (geometric) prolongations, the fallback on a P-matrix where the active-set steps cycle, and
// every kind of ζ.
#include "common.hpp"

#include <doctest/doctest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

using namespace nrmicp;

namespace {
using RowMat = testing::SpMat<int, Eigen::RowMajor>;
using Vec = Eigen::VectorXd;

/// −Δ_h (5-point) on m × m interior nodes of the unit square, h = 1/(m + 1).
RowMat laplacian_2d(int m) {
  const double s = (m + 1.0) * (m + 1.0);
  std::vector<Eigen::Triplet<double>> t;
  for (int b = 0; b < m; ++b)
    for (int i = 0; i < m; ++i) {
      const int r = b * m + i;
      t.emplace_back(r, r, 4 * s);
      if (i > 0) t.emplace_back(r, r - 1, -s);
      if (i + 1 < m) t.emplace_back(r, r + 1, -s);
      if (b > 0) t.emplace_back(r, r - m, -s);
      if (b + 1 < m) t.emplace_back(r, r + m, -s);
    }
  RowMat A(m * m, m * m);
  A.setFromTriplets(t.begin(), t.end());
  return A;
}

/// Linear interpolation from mc = (m − 1)/2 coarse nodes to m fine nodes (1D), and its 2D tensor.
RowMat interpolation_2d(int m) {
  const int mc = (m - 1) / 2;
  std::vector<Eigen::Triplet<double>> t;
  auto p1 = [&](int i, int j) {  // weight of coarse node j at fine node i
    const int centre = 2 * j + 1;
    return i == centre ? 1.0 : (std::abs(i - centre) == 1 ? 0.5 : 0.0);
  };
  for (int by = 0; by < m; ++by)
    for (int bx = 0; bx < m; ++bx)
      for (int cy = std::max(0, (by - 1) / 2); cy <= std::min(mc - 1, by / 2); ++cy)
        for (int cx = std::max(0, (bx - 1) / 2); cx <= std::min(mc - 1, bx / 2); ++cx) {
          const double wgt = p1(bx, cx) * p1(by, cy);
          if (wgt > 0) t.emplace_back(by * m + bx, cy * mc + cx, wgt);
        }
  RowMat P(m * m, mc * mc);
  P.setFromTriplets(t.begin(), t.end());
  return P;
}

/// The geometric hierarchy of an m × m grid (m = 2^k − 1): prolongations down to 3 × 3.
std::vector<RowMat> hierarchy_2d(int m) {
  std::vector<RowMat> P;
  for (int mm = m; mm >= 7; mm = (mm - 1) / 2) P.push_back(interpolation_2d(mm));
  return P;
}

/// The membrane obstacle ψ = 0.1 − (x − ½)² − (y − ½)².
Vec paraboloid(int m) {
  Vec psi(m * m);
  for (int b = 0; b < m; ++b)
    for (int i = 0; i < m; ++i) {
      const double x = (i + 1.0) / (m + 1), y = (b + 1.0) / (m + 1);
      psi[b * m + i] = 0.1 - (x - 0.5) * (x - 0.5) - (y - 0.5) * (y - 0.5);
    }
  return psi;
}

/// Projected Gauss–Seidel for min(Az + q, z − ψ) = 0, run far past convergence: an independent
/// reference for an M-matrix.
Vec projected_gauss_seidel(const RowMat& A, const Vec& q, const Vec& psi, int sweeps) {
  Vec z = psi.cwiseMax(0.0);
  for (int k = 0; k < sweeps; ++k)
    for (int i = 0; i < A.rows(); ++i) {
      double off = 0, d = 0;
      for (RowMat::InnerIterator it(A, i); it; ++it) (it.col() == i ? d : off) += it.value() * (it.col() == i ? 1 : z[it.col()]);
      z[i] = std::max(psi[i], -(q[i] + off) / d);
    }
  return z;
}

void check_complementarity(const RowMat& A, const Vec& q, const Vec& z, const Vec& zeta_z, double tol) {
  const Vec w = A * z + q, g = z - zeta_z;
  CHECK(w.cwiseMin(g).norm() < tol);
  CHECK(w.minCoeff() > -tol);
  CHECK(g.minCoeff() > -tol);
  CHECK(std::abs(g.cwiseProduct(w).sum()) < tol * (1 + z.norm()));
}
}  // namespace

TEST_CASE("Newton solves Bai's LCP and constant-obstacle problems with known solutions") {
  for (bool symmetric : {true, false}) {
    const RowMat A = testing::bai<int, Eigen::RowMajor>(12, 4.0, symmetric);
    const auto k = testing::known_solution(A.rows());
    Options o;
    o.tol = 1e-12;
    const Newton<RowMat> newton(A, o);
    const Vec q = k.w - A * k.g;
    Result r = newton.solve(q);
    CHECK(r.status == Status::Converged);
    CHECK((r.z - k.g).lpNorm<Eigen::Infinity>() < 1e-12);
    CHECK(r.newton.path == "newton");
    CHECK(r.nit <= 5);
    CHECK(r.newton.linear_solves == r.nit);
    // ζ ≡ c: z* = g* + c.
    const Vec c = Vec::LinSpaced(A.rows(), -1.0, 1.0);
    const Vec qc = k.w - A * (k.g + c);
    r = newton.solve(qc, Zeta<int>::constant(c));
    CHECK(r.status == Status::Converged);
    CHECK((r.z - (k.g + c)).lpNorm<Eigen::Infinity>() < 1e-12);
  }
}

TEST_CASE("Newton with user-supplied prolongations: the obstacle problem in 2D, few fine steps") {
  const int m = 31;  // 31 -> 15 -> 7 -> 3
  const RowMat A = laplacian_2d(m);
  const Vec psi = paraboloid(m), q = Vec::Zero(m * m);
  const std::vector<RowMat> P = hierarchy_2d(m);
  Options o;
  o.tol = 1e-9;
  const Newton<RowMat> nested(A, o, P), cold(A, o);
  CHECK(nested.levels() == 4);
  const Result rn = nested.solve(q, Zeta<int>::constant(psi));
  const Result rc = cold.solve(q, Zeta<int>::constant(psi));
  CHECK(rn.status == Status::Converged);
  CHECK(rc.status == Status::Converged);
  CHECK(rn.nit <= 3);          // started from the coarse solutions
  CHECK(rn.nit < rc.nit);      // the cold start peels the contact set
  CHECK(rn.newton.level_steps.size() == 4);
  CHECK(rn.newton.level_seconds.size() == 4);
  CHECK(rn.newton.linear_solves > rn.nit);  // coarse levels solve too
  check_complementarity(A, q, rn.z, psi, 1e-9);
  const Vec ref = projected_gauss_seidel(A, q, psi, 4000);
  CHECK((rn.z - ref).lpNorm<Eigen::Infinity>() < 1e-8);
  CHECK((rn.z - rc.z).lpNorm<Eigen::Infinity>() < 1e-12);
}

TEST_CASE("inner = cg: multigrid-preconditioned CG on the reduced systems agrees with the direct solve") {
  const int m = 31;
  const RowMat A = laplacian_2d(m);
  const Vec psi = paraboloid(m), q = Vec::Zero(m * m);
  const std::vector<RowMat> P = hierarchy_2d(m);
  Options o;
  o.tol = 1e-10;
  o.method = Method::Newton;
  o.inner = Inner::EigenLLT;  // a direct solve (auto takes CG where there is a hierarchy)
  const Newton<RowMat> direct(A, o, P);
  o.inner = Inner::CG;
  const Newton<RowMat> cg(A, o, P);
  const Result rd = direct.solve(q, Zeta<int>::constant(psi));
  const Result rc = cg.solve(q, Zeta<int>::constant(psi));
  CHECK(std::string(rc.inner) == "cg");
  CHECK(std::string(rd.inner) != "cg");
  CHECK(rc.status == Status::Converged);
  CHECK(rc.residual < 1e-10);
  CHECK(rc.nit <= 4);  // the last set solved loosely, then again exactly (NewtonControl::repeat_trust = 0)
  check_complementarity(A, q, rc.z, psi, 1e-10);
  CHECK((rc.z - rd.z).lpNorm<Eigen::Infinity>() < 1e-10);
  const Vec ref = projected_gauss_seidel(A, q, psi, 4000);
  CHECK((rc.z - ref).lpNorm<Eigen::Infinity>() < 1e-8);
  // Without a hierarchy, or for a stationary member, cg does not apply.
  const Newton<RowMat> no_hierarchy(A, o);
  CHECK(std::string(no_hierarchy.solve(q, Zeta<int>::constant(psi)).inner) != "cg");
  Options s;
  s.method = Method::NRM;
  s.inner = Inner::CG;
  CHECK_THROWS_WITH_AS(Solver<RowMat>(A, s), doctest::Contains("inner = 'cg'"), std::invalid_argument);
}

namespace {
/// K of an LCP step for the inactive set (detail/active_set.hpp): A's inactive rows with the
/// active columns zeroed, identity rows on the active set.
detail::MultigridKrylov<int>::ColMatrix lcp_system(const RowMat& A, const std::vector<char>& inactive) {
  detail::MultigridKrylov<int>::ColMatrix K = A;
  for (int j = 0; j < K.outerSize(); ++j)
    for (detail::MultigridKrylov<int>::ColMatrix::InnerIterator it(K, j); it; ++it)
      it.valueRef() = inactive[it.row()] ? (inactive[j] ? it.value() : 0.0) : (it.row() == j ? 1.0 : 0.0);
  return K;
}

/// The entries of `now` that differ from `before` (same pattern), as setup's changes.
std::vector<detail::Change<int>> changes(const detail::MultigridKrylov<int>::ColMatrix& before,
                                         const detail::MultigridKrylov<int>::ColMatrix& now) {
  std::vector<detail::Change<int>> out;
  for (int j = 0; j < now.outerSize(); ++j)
    for (int p = now.outerIndexPtr()[j]; p < now.outerIndexPtr()[j + 1]; ++p)
      if (now.valuePtr()[p] != before.valuePtr()[p])
        out.push_back({now.innerIndexPtr()[p], j, now.valuePtr()[p] - before.valuePtr()[p]});
  return out;
}

/// The levels of hierarchy_2d(m) below A, each with its Galerkin operator.
std::vector<detail::Level<int>> galerkin_levels(const RowMat& A, int m) {
  std::vector<detail::Level<int>> levels;
  RowMat coarse = A;
  for (const RowMat& P : hierarchy_2d(m)) {
    detail::Level<int> level{P, RowMat(P.transpose()), {}};
    level.A = detail::product(level.R, detail::product(coarse, level.P));
    coarse = level.A;
    levels.push_back(level);
  }
  return levels;
}
}  // namespace

TEST_CASE("one Newton with inner = cg solves again and again (its V-cycle frees the coarse operators while the finest level solves)") {
  const int m = 31;
  const RowMat A = laplacian_2d(m);
  const Vec psi = paraboloid(m), q = Vec::Zero(m * m);
  Options o;
  o.tol = 1e-10;
  o.inner = Inner::CG;
  const Newton<RowMat> cg(A, o, hierarchy_2d(m));
  o.inner = Inner::Auto;
  const Newton<RowMat> direct(A, o, hierarchy_2d(m));
  RowMat B(m * m, m * m);
  B.setIdentity();
  B *= 0.3;
  const Vec c = 0.7 * psi;
  // nested, polish (finest level only, the operators kept lent), affine ζ (a copy of them), nested again
  for (int k = 0; k < 2; ++k) {
    const Vec psi_k = (1.0 + 0.5 * k) * psi;
    const Result rc = cg.solve(q, Zeta<int>::constant(psi_k)), rd = direct.solve(q, Zeta<int>::constant(psi_k));
    CHECK(std::string(rc.inner) == "cg");
    CHECK(rc.status == Status::Converged);
    CHECK(rc.nit <= 4);
    CHECK((rc.z - rd.z).lpNorm<Eigen::Infinity>() < 1e-10);
    const Result pc = cg.polish(q, Zeta<int>::constant(psi_k), rc.z, 1e-12);
    CHECK(pc.residual <= rc.residual);
    const Result ac = cg.solve(q, Zeta<int>::affine(B, c)), ad = direct.solve(q, Zeta<int>::affine(B, c));
    CHECK(ac.status == Status::Converged);
    CHECK((ac.z - ad.z).lpNorm<Eigen::Infinity>() < 1e-10);
  }
}

TEST_CASE("the V-cycle updated by K's changed entries equals the one set up afresh; many changes take the full set-up") {
  const int m = 31, n = m * m;
  const RowMat A = laplacian_2d(m);
  std::vector<detail::Level<int>> levels = galerkin_levels(A, m);
  const detail::Hierarchy<int> below{levels.data(), levels.size()};
  // Active sets: a disc growing by a few points a step, then all but one point flipped (more
  // changes than max_changes: the full set-up), then a small change again.
  auto disc = [&](double radius) {
    std::vector<char> inactive(n, 1);
    for (int i = 0; i < n; ++i) {
      const double x = i % m - m / 2.0, y = i / m - m / 2.0;
      if (x * x + y * y < radius * radius) inactive[i] = 0;
    }
    return inactive;
  };
  std::vector<std::vector<char>> sets = {disc(5), disc(5.5), disc(6.2), disc(6.2)};
  sets.push_back(sets.back());
  for (int i = 1; i < n; ++i) sets.back()[i] = !sets.back()[i];
  sets.push_back(sets.back());
  sets.back()[n / 2 + 3] = !sets.back()[n / 2 + 3];
  detail::MultigridKrylov<int> updated(below, true);
  std::vector<detail::MultigridKrylov<int>::ColMatrix> K;
  Vec r(n);
  for (int i = 0; i < n; ++i) r[i] = std::sin(0.37 * i) + 0.5;
  for (std::size_t k = 0; k < sets.size(); ++k) {
    K.push_back(lcp_system(A, sets[k]));
    const auto dK = k ? changes(K[k - 1], K[k]) : std::vector<detail::Change<int>>{};
    CHECK((k != 4 || dK.size() > detail::MultigridKrylov<int>::max_changes(K[k].nonZeros())));
    REQUIRE(updated.setup(K[k], k ? &dK : nullptr));
    detail::MultigridKrylov<int> fresh(below, true);
    REQUIRE(fresh.setup(K[k]));
    Vec e_updated, e_fresh;
    updated.precondition(r, e_updated);
    fresh.precondition(r, e_fresh);
    CAPTURE(k);
    CHECK((e_updated - e_fresh).norm() <= 1e-12 * e_fresh.norm());
  }
  // Started from the hierarchy's operators (those of K = A), the first set-up is an update too.
  for (const auto& set : {disc(2), disc(12)}) {   // few changes from A, and more than max_changes
    const detail::MultigridKrylov<int>::ColMatrix K_A = A, K_set = lcp_system(A, set);
    const auto from_A = changes(K_A, K_set);
    detail::MultigridKrylov<int> seeded(below, true), fresh(below, true);
    seeded.start_from_hierarchy(K_A.nonZeros());
    REQUIRE(seeded.setup(K_set, &from_A));
    REQUIRE(fresh.setup(K_set));
    Vec e_seeded, e_fresh;
    seeded.precondition(r, e_seeded);
    fresh.precondition(r, e_fresh);
    CHECK((e_seeded - e_fresh).norm() <= 1e-12 * e_fresh.norm());
  }
  // Borrowed (`borrow`): the hierarchy holds no operators while the V-cycle works; restored,
  // they are the Galerkin operators of A again, and the V-cycle goes on from its own.
  {
    std::vector<RowMat> before;
    for (const auto& level : levels) before.push_back(level.A);
    const detail::MultigridKrylov<int>::ColMatrix K_A = A;
    detail::MultigridKrylov<int> borrowing(below, true, true);
    borrowing.start_from_hierarchy(K_A.nonZeros());
    detail::MultigridKrylov<int>::ColMatrix previous = K_A;
    for (const auto& set : {disc(2), disc(12), disc(3)}) {
      const detail::MultigridKrylov<int>::ColMatrix K_set = lcp_system(A, set);
      const auto dK = changes(previous, K_set);
      REQUIRE(borrowing.setup(K_set, &dK));
      CHECK(borrowing.lent());
      for (const auto& level : levels) CHECK(level.A.nonZeros() == 0);
      detail::MultigridKrylov<int> fresh(below, true);
      REQUIRE(fresh.setup(K_set));
      Vec e_borrowing, e_fresh;
      borrowing.precondition(r, e_borrowing);
      fresh.precondition(r, e_fresh);
      CHECK((e_borrowing - e_fresh).norm() <= 1e-12 * e_fresh.norm());
      borrowing.restore_hierarchy(K_A);
      CHECK_FALSE(borrowing.lent());
      for (std::size_t l = 0; l < levels.size(); ++l) {
        REQUIRE(levels[l].A.nonZeros() == before[l].nonZeros());
        CHECK((RowMat(levels[l].A - before[l])).norm() <= 1e-13 * before[l].norm());
      }
      previous = K_set;
    }
  }
  // A failed set-up (a NaN in K) is not updated from: the next one is a full set-up.
  detail::MultigridKrylov<int>::ColMatrix bad = K.back();
  bad.valuePtr()[0] = std::numeric_limits<double>::quiet_NaN();
  CHECK_FALSE(updated.setup(bad, nullptr));
  const auto dK = changes(bad, K[0]);
  REQUIRE(updated.setup(K[0], &dK));
  detail::MultigridKrylov<int> fresh(below, true);
  REQUIRE(fresh.setup(K[0]));
  Vec e_updated, e_fresh;
  updated.precondition(r, e_updated);
  fresh.precondition(r, e_fresh);
  CHECK((e_updated - e_fresh).norm() <= 1e-12 * e_fresh.norm());
}

/// laplacian_2d(m) plus first-order upwind convection (b_x, b_y) ≥ 0: a nonsymmetric M-matrix.
RowMat convection_2d(int m, double bx, double by) {
  const double s = m + 1.0;
  RowMat C(m * m, m * m);
  std::vector<Eigen::Triplet<double>> t;
  for (int b = 0; b < m; ++b)
    for (int i = 0; i < m; ++i) {
      const int r = b * m + i;
      t.emplace_back(r, r, (bx + by) * s);
      if (i > 0) t.emplace_back(r, r - 1, -bx * s);
      if (b > 0) t.emplace_back(r, r - m, -by * s);
    }
  C.setFromTriplets(t.begin(), t.end());
  return RowMat(laplacian_2d(m) + C);
}

TEST_CASE("inner = cg on a nonsymmetric A: BiCGSTAB preconditioned by the V-cycle agrees with the direct solve") {
  const int m = 31;
  const RowMat A = convection_2d(m, 40.0, 20.0);
  const Vec psi = paraboloid(m), q = Vec::Zero(m * m);
  const std::vector<RowMat> P = hierarchy_2d(m);
  Options o;
  o.tol = 1e-10;
  o.method = Method::Newton;
  o.inner = Inner::Umfpack;
  const Result rd = Newton<RowMat>(A, o, P).solve(q, Zeta<int>::constant(psi));
  o.inner = Inner::CG;
  const Result rk = Newton<RowMat>(A, o, P).solve(q, Zeta<int>::constant(psi));
  CHECK(std::string(rk.inner) == "bicgstab");
  CHECK(rk.status == Status::Converged);
  CHECK(rk.residual < 1e-10);
  CHECK(rk.newton.inner_iterations > 0);
  check_complementarity(A, q, rk.z, psi, 1e-10);
  CHECK((rk.z - rd.z).lpNorm<Eigen::Infinity>() < 1e-10);
  const Vec ref = projected_gauss_seidel(A, q, psi, 4000);  // A is an M-matrix: PGS converges
  CHECK((rk.z - ref).lpNorm<Eigen::Infinity>() < 1e-8);
}

TEST_CASE("inner = cg on a nonsymmetric A: one Newton solves again (the coarse operators formed again from A's rows)") {
  const int m = 31;
  const RowMat A = convection_2d(m, 40.0, 20.0);
  const Vec psi = paraboloid(m), q = Vec::Zero(m * m);
  Options o;
  o.tol = 1e-10;
  o.inner = Inner::CG;
  const Newton<RowMat> krylov(A, o, hierarchy_2d(m));
  o.inner = Inner::Umfpack;
  const Newton<RowMat> direct(A, o, hierarchy_2d(m));
  const Result first = krylov.solve(q, Zeta<int>::constant(psi));
  for (double scale : {1.5, 1.0}) {
    const Result rk = krylov.solve(q, Zeta<int>::constant(scale * psi));
    const Result rd = direct.solve(q, Zeta<int>::constant(scale * psi));
    CHECK(std::string(rk.inner) == "bicgstab");
    CHECK(rk.status == Status::Converged);
    CHECK((rk.z - rd.z).lpNorm<Eigen::Infinity>() < 1e-10);
  }
  // The operators formed again are A's Galerkin ones (read through the row copy of a nonsymmetric K).
  std::vector<detail::Level<int>> levels = galerkin_levels(A, m);
  const std::vector<detail::Level<int>> before = levels;
  const detail::MultigridKrylov<int>::ColMatrix K_A = A;
  std::vector<char> inactive(m * m, 1);
  for (int i = 0; i < m * m; i += 3) inactive[i] = 0;
  const detail::MultigridKrylov<int>::ColMatrix K_set = lcp_system(A, inactive);
  detail::MultigridKrylov<int> borrowing({levels.data(), levels.size()}, false, true);
  borrowing.start_from_hierarchy(K_A.nonZeros());
  REQUIRE(borrowing.setup(K_set));
  borrowing.restore_hierarchy(K_A);
  for (std::size_t l = 0; l < levels.size(); ++l)
    CHECK((RowMat(levels[l].A - before[l].A)).norm() <= 1e-13 * before[l].A.norm());
  const Result again = krylov.solve(q, Zeta<int>::constant(psi));   // the same coarse problems as the first
  CHECK(again.newton.level_steps == first.newton.level_steps);
  CHECK(again.newton.linear_solves == first.newton.linear_solves);
  CHECK((again.z - first.z).lpNorm<Eigen::Infinity>() < 1e-12);
}

/// The textbook V-cycle on dense matrices: forward Gauss–Seidel from 0, the residual r − K e,
/// the coarse correction, backward Gauss–Seidel; the coarsest level solved exactly.
static Vec textbook_vcycle(const std::vector<Eigen::MatrixXd>& K, const std::vector<Eigen::MatrixXd>& P, std::size_t l,
                    const Vec& r) {
  if (l == P.size()) return K[l].lu().solve(r);
  const Eigen::Index n = r.size();
  Vec e = Vec::Zero(n);
  auto sweep = [&](bool forward) {
    for (Eigen::Index t = 0; t < n; ++t) {
      const Eigen::Index i = forward ? t : n - 1 - t;
      e[i] += (r[i] - K[l].row(i).dot(e)) / K[l](i, i);
    }
  };
  sweep(true);
  e += P[l] * textbook_vcycle(K, P, l + 1, P[l].transpose() * (r - K[l] * e));
  sweep(false);
  return e;
}

/// convection_2d(m) with couplings three lines ahead, k_{i,i+3m} = −w (diagonal raised by w):
/// its rows reach 3m right of the diagonal and m left, unlike its columns.
RowMat lopsided_2d(int m, double w) {
  RowMat C(m * m, m * m);
  std::vector<Eigen::Triplet<double>> t;
  for (int i = 0; i < m * m; ++i)
    if (i + 3 * m < m * m) {
      t.emplace_back(i, i + 3 * m, -w);
      t.emplace_back(i, i, w);
    }
  C.setFromTriplets(t.begin(), t.end());
  return RowMat(convection_2d(m, 40.0, 20.0) + C);
}

TEST_CASE("one V-cycle is the textbook one: the forward sweep leaves its residual in the same pass (symmetric) or rows behind it (nonsymmetric), after set-up, update, borrow and restore") {
  const int m = 15, n = m * m;
  Vec r(n);
  for (int i = 0; i < n; ++i) r[i] = std::cos(0.41 * i) - 0.2;
  std::vector<char> first(n, 1), second(n, 1);
  for (int i = 0; i < n; i += 5) first[i] = 0;
  for (int i = 0; i < n; i += 7) second[i] = 0;
  for (const int kind : {0, 1, 2}) {   // symmetric, nonsymmetric, nonsymmetric with rows reaching 3m
    CAPTURE(kind);
    const bool symmetric = kind == 0;
    const RowMat A = kind == 0 ? laplacian_2d(m) : kind == 1 ? convection_2d(m, 40.0, 20.0) : lopsided_2d(m, 30.0);
    std::vector<detail::Level<int>> levels = galerkin_levels(A, m);
    const detail::Hierarchy<int> below{levels.data(), levels.size()};
    auto check = [&](const detail::MultigridKrylov<int>& cycle, const detail::MultigridKrylov<int>::ColMatrix& K) {
      std::vector<Eigen::MatrixXd> Kd{Eigen::MatrixXd(K)}, Pd;
      for (const auto& level : levels) {
        Pd.emplace_back(level.P);
        Kd.push_back(Pd.back().transpose() * Kd.back() * Pd.back());
      }
      const Vec ref = textbook_vcycle(Kd, Pd, 0, r);
      Vec e;
      cycle.precondition(r, e);
      CHECK((e - ref).norm() <= 1e-11 * ref.norm());
      cycle.precondition(r, e);   // again: no state left from the first application
      CHECK((e - ref).norm() <= 1e-11 * ref.norm());
    };
    const detail::MultigridKrylov<int>::ColMatrix K_A = A, K1 = lcp_system(A, first), K2 = lcp_system(A, second);
    const auto to_second = changes(K1, K2);
    detail::MultigridKrylov<int> fresh(below, symmetric);
    REQUIRE(fresh.setup(K1));
    check(fresh, K1);
    REQUIRE(fresh.setup(K2, &to_second));   // updated by K's changes
    check(fresh, K2);
    // borrowing the hierarchy's operators, then forming them again from A and updating once more
    detail::MultigridKrylov<int> borrowing(below, symmetric, true);
    borrowing.start_from_hierarchy(K_A.nonZeros());
    const auto from_A = changes(K_A, K1);
    REQUIRE(borrowing.setup(K1, &from_A));
    check(borrowing, K1);
    borrowing.restore_hierarchy(K_A);
    REQUIRE(borrowing.setup(K2, &to_second));
    check(borrowing, K2);
  }
}

TEST_CASE("a Krylov solve that does not converge is redone by the direct solve: the exact step") {
  const int m = 15;
  const RowMat A = convection_2d(m, 40.0, 20.0);
  detail::Level<int> coarse{interpolation_2d(m), {}, {}};
  coarse.R = coarse.P.transpose();  // the V-cycle reads P and R; A is the Newton member's
  detail::ActiveSetSystem<int> iterative(A, nullptr, Inner::CG, {&coarse, 1});
  detail::ActiveSetSystem<int> direct(A, nullptr, Inner::Umfpack);
  CHECK(std::string(iterative.inner_name()) == "bicgstab");
  std::vector<char> inactive(m * m);
  for (int i = 0; i < m * m; ++i) inactive[i] = (i % 7) != 0;
  REQUIRE(iterative.factorize(inactive));
  REQUIRE(direct.factorize(inactive));
  const Vec b = Vec::LinSpaced(m * m, -1.0, 1.0);
  Vec zd = Vec::Zero(m * m), zk = Vec::Zero(m * m);
  direct.solve(b, zd);
  iterative.set_max_iterations(1);
  CHECK(iterative.solve(b, zk, 1e-14) == 2);  // not converged in 1 iteration: reported as max + 1
  CHECK((zk - zd).lpNorm<Eigen::Infinity>() < 1e-12 * zd.lpNorm<Eigen::Infinity>());
  iterative.set_max_iterations(500);  // converges: the Krylov iterate, to the target
  zk.setZero();
  const int k = iterative.solve(b, zk, 1e-10);
  CHECK(k >= 1);
  CHECK(k <= 500);
  CHECK((zk - zd).lpNorm<Eigen::Infinity>() < 1e-8);
}

TEST_CASE("a coarse operator with a non-positive diagonal ends the hierarchy there, and hierarchy() says where") {
  const int m = 31;  // 31 -> 15 -> 7 -> 3
  const RowMat A = laplacian_2d(m);
  const Vec psi = paraboloid(m), q = Vec::Zero(m * m);
  std::vector<RowMat> P = hierarchy_2d(m);
  const Newton<RowMat> kept(A, Options(), P);
  CHECK(kept.hierarchy().requested == 4);
  CHECK(kept.hierarchy().used == 4);
  CHECK(kept.hierarchy().reason.empty());
  // column 5 of P_1 emptied: (P_1ᵀ A_1 P_1)_55 = 0, so level 2 and the levels below it go
  for (int k = P[1].outerIndexPtr()[0]; k < P[1].outerIndexPtr()[P[1].rows()]; ++k)
    if (P[1].innerIndexPtr()[k] == 5) P[1].valuePtr()[k] = 0.0;
  Options o;
  o.tol = 1e-9;
  const Newton<RowMat> cut(A, o, P);
  CHECK(cut.levels() == 2);
  CHECK(cut.hierarchy().requested == 4);
  CHECK(cut.hierarchy().used == 2);
  CHECK(cut.hierarchy().reason.find("level 2 (prolongations[1]) has a_ii = 0 <= 0 at row 5") != std::string::npos);
  const Result r = cut.solve(q, Zeta<int>::constant(psi));
  CHECK(r.status == Status::Converged);
  CHECK(r.newton.level_steps.size() == 2);
  check_complementarity(A, q, r.z, psi, 1e-9);
}

TEST_CASE("a prolongation of the wrong shape is refused, naming it") {
  const RowMat A = laplacian_2d(7);
  std::vector<RowMat> P{interpolation_2d(15)};
  CHECK_THROWS_WITH_AS(Newton<RowMat>(A, Options(), P), doctest::Contains("prolongations[0]"), std::invalid_argument);
}

TEST_CASE("coarse operators given with the prolongations are taken as the Galerkin ones; a wrong count or shape is refused") {
  const int m = 31;
  const RowMat A = laplacian_2d(m);
  const Vec psi = paraboloid(m), q = Vec::Zero(m * m);
  const std::vector<RowMat> P = hierarchy_2d(m);
  std::vector<RowMat> C;  // P_lᵀ A_l P_l, formed here independently of the library
  RowMat Al = A;
  for (const RowMat& Pl : P) {
    RowMat next = RowMat(RowMat(Pl.transpose()) * Al) * Pl;
    C.push_back(next);
    Al = next;
  }
  Options o;
  o.tol = 1e-9;
  const Newton<RowMat> formed(A, o, P), given(A, o, P, C);
  const Result rf = formed.solve(q, Zeta<int>::constant(psi)), rg = given.solve(q, Zeta<int>::constant(psi));
  CHECK(rg.status == Status::Converged);
  CHECK(rg.newton.level_steps == rf.newton.level_steps);
  CHECK((rg.z - rf.z).lpNorm<Eigen::Infinity>() < 1e-12);
  // a coarse operator that is not the Galerkin one is taken as it is: the coarse level solves it
  std::vector<RowMat> scaled = C;
  scaled[0] *= 2.0;
  const Result rs = Newton<RowMat>(A, o, P, scaled).solve(q, Zeta<int>::constant(psi));
  CHECK(rs.status == Status::Converged);
  check_complementarity(A, q, rs.z, psi, 1e-9);
  const std::vector<RowMat> one(C.begin(), C.begin() + 1);
  CHECK_THROWS_WITH_AS(Newton<RowMat>(A, o, P, one), doctest::Contains("coarse_operators for"), std::invalid_argument);
  std::vector<RowMat> wrong = C;
  wrong[1] = C[0];
  CHECK_THROWS_WITH_AS(Newton<RowMat>(A, o, P, wrong), doctest::Contains("coarse_operators[1]"), std::invalid_argument);
}

TEST_CASE("a P-matrix on which the active-set steps cycle: the fallback is taken and the answer is right") {
  // A P-matrix, not an M-matrix (found by search: from z = 0 the Newton steps, each followed by its
  // projected Gauss-Seidel sweeps, return to an active set seen before). Its unique solution, by
  // enumeration of the 8 active sets:
  std::vector<Eigen::Triplet<double>> t{{0, 0, 1}, {0, 1, -1.5}, {0, 2, -2.5}, {1, 1, 1.5}, {1, 2, -0.5},
                                        {2, 0, 3}, {2, 1, -0.5}, {2, 2, 1.5}};
  RowMat A(3, 3);
  A.setFromTriplets(t.begin(), t.end());
  const Vec q = (Vec(3) << 1.3, -0.1, -0.9).finished();
  Vec z_star;
  for (int mask = 0; mask < 8; ++mask) {
    Eigen::MatrixXd K = Eigen::MatrixXd::Identity(3, 3);
    Vec b = Vec::Zero(3);
    for (int i = 0; i < 3; ++i)
      if (mask >> i & 1) { K.row(i) = Eigen::MatrixXd(A).row(i); b[i] = -q[i]; }
    const Vec z = K.fullPivLu().solve(b), w = A * z + q;
    if (z.minCoeff() >= -1e-14 && w.minCoeff() >= -1e-14) z_star = z;
  }
  REQUIRE(z_star.size() == 3);
  Options o;
  o.tol = 1e-10;
  const Result r = Newton<RowMat>(A, o).solve(q);
  CHECK(r.status == Status::Converged);
  CHECK(r.newton.fallback_sweeps > 0);
  CHECK(r.newton.path.find("fallback") != std::string::npos);
  CHECK((r.z - z_star).lpNorm<Eigen::Infinity>() < 1e-9);
}

TEST_CASE("Newton on ICPs: affine ζ (full system) and a functor ζ (outer fixed point)") {
  const RowMat A = testing::bai<int, Eigen::RowMajor>(10, 4.0, false);
  const Eigen::Index n = A.rows();
  const auto k = testing::known_solution(n);
  const Vec z_star = k.g + Vec::Constant(n, 0.5);
  // Affine: ζ(z) = Bz + c, B = 0.2 × (shift by one).
  std::vector<Eigen::Triplet<double>> t;
  for (Eigen::Index i = 0; i + 1 < n; ++i) t.emplace_back(i, i + 1, 0.2);
  Zeta<int>::RowMatrix B(n, n);
  B.setFromTriplets(t.begin(), t.end());
  const Vec c = z_star - k.g - B * z_star;
  const Vec q = k.w - A * z_star;
  Options o;
  o.tol = 1e-11;
  const Newton<RowMat> newton(A, o);
  Result r = newton.solve(q, Zeta<int>::affine(B, c));
  CHECK(r.status == Status::Converged);
  CHECK((r.z - z_star).lpNorm<Eigen::Infinity>() < 1e-10);
  check_complementarity(A, q, r.z, B * r.z + c, 1e-10);
  // Functor: ζ(z) = 0.1 sin z + s.
  const Vec s = z_star - k.g - 0.1 * z_star.array().sin().matrix();
  const auto zeta = Zeta<int>::functor([&](const double* z, double* out, Eigen::Index nn) {
    for (Eigen::Index i = 0; i < nn; ++i) out[i] = 0.1 * std::sin(z[i]) + s[i];
    return true;
  });
  r = newton.solve(q, zeta);
  CHECK(r.status == Status::Converged);
  CHECK(r.newton.outer_iterations >= 2);
  CHECK((r.z - z_star).lpNorm<Eigen::Infinity>() < 1e-10);
}

TEST_CASE("Newton: warm start from the solution, maxiter, callback stop, tol below rounding") {
  const RowMat A = testing::bai<int, Eigen::RowMajor>(8, 4.0, true);
  const auto k = testing::known_solution(A.rows());
  const Vec q = k.w - A * k.g;
  Options o;
  o.tol = 1e-10;
  const Newton<RowMat> newton(A, o);
  Result r = newton.solve(q, Zeta<int>::none(), &k.g);
  CHECK(r.status == Status::Converged);
  CHECK(r.nit == 0);
  Options it = o;
  it.maxiter = 0;
  r = newton.solve(q, Zeta<int>::none(), nullptr, {}, {}, &it);
  CHECK(r.status == Status::MaxIterations);
  r = newton.solve(q, Zeta<int>::none(), nullptr, [](int, const Vec&, double) { return true; });
  CHECK(r.status == Status::CallbackStop);
  it = o;
  it.tol = 1e-300;
  r = newton.solve(q, Zeta<int>::none(), nullptr, {}, {}, &it);
  CHECK(r.status == Status::Stagnated);
  CHECK(r.residual < 1e-12);
}

// Traps of the C++ API (issue 13): each of these ran silently before.
TEST_CASE("nrmicp::Solver refuses Method::Newton, naming nrmicp::Newton") {
  const RowMat A = testing::bai<int, Eigen::RowMajor>(4, 4.0, true);
  Options o;
  o.method = Method::Newton;
  CHECK_THROWS_WITH_AS(Solver<RowMat>(A, o), doctest::Contains("nrmicp::Newton"), std::invalid_argument);
  CHECK_FALSE(is_aor_type(Method::Newton));
}

TEST_CASE("nrmicp::Newton refuses phi, accelerate and z_update, at set-up and per solve") {
  const RowMat A = testing::bai<int, Eigen::RowMajor>(4, 4.0, true);
  const Vec q = -Vec::Ones(A.rows());
  for (Method m : {Method::Newton, Method::NRMGS}) {  // the class is the Newton member, whatever method says
    CAPTURE(to_string(m));
    Options phi, anderson, solve_update;
    phi.method = anderson.method = solve_update.method = m;
    phi.phi = Vec::Constant(A.rows(), 0.1);
    anderson.accelerate = Accelerate::Anderson;
    solve_update.z_update = ZUpdate::Solve;
    CHECK_THROWS_WITH_AS(Newton<RowMat>(A, phi), doctest::Contains("phi"), std::invalid_argument);
    CHECK_THROWS_WITH_AS(Newton<RowMat>(A, anderson), doctest::Contains("accelerate"), std::invalid_argument);
    CHECK_THROWS_WITH_AS(Newton<RowMat>(A, solve_update), doctest::Contains("z_update"), std::invalid_argument);
    const Newton<RowMat> newton(A, Options());
    CHECK_THROWS_WITH_AS(newton.solve(q, Zeta<int>::none(), nullptr, {}, {}, &anderson),
                         doctest::Contains("accelerate"), std::invalid_argument);
  }
  Options o;
  o.method = Method::Newton;
  CHECK_NOTHROW(o.check(A.rows()));
}

TEST_CASE("nrmicp::Newton fills timings.iterations") {
  const RowMat A = laplacian_2d(31);
  const Vec psi = paraboloid(31), q = Vec::Zero(31 * 31);
  Options o;
  o.record_history = true;
  for (const auto& zeta : {Zeta<int>::constant(psi), Zeta<int>::affine(Zeta<int>::RowMatrix(A.rows(), A.rows()), psi)}) {
    const Result r = Newton<RowMat>(A, o).solve(q, zeta);
    REQUIRE(r.status == Status::Converged);
    CHECK(r.timings.iterations > 0);
    CHECK(r.timings.iterations <= r.timings.total);
    CHECK(r.timings.iterations >= r.history_seconds.back());
    // every phase of the steps timed, each inside its container (docs/SPEC.md, "Timings")
    const Timings& t = r.timings;
    CHECK(t.factorization > 0);
    CHECK(t.inner_solve > 0);
    CHECK(t.spmv > 0);
    CHECK(t.setup > 0);  // the reduced system's analysis, on first use
    CHECK(t.setup + t.iterations <= t.total + 1e-6);
    CHECK(t.factorization + t.zeta + t.spmv + t.inner_solve <= t.iterations + 1e-6);
  }
}

TEST_CASE("Newton stops at the rounding floor of Res, in a few steps, and says what the floor was") {
  // A degenerate LCP (z* = 0 and w* = 0 on a band of nodes) with A ~ 1e12: Res cannot get below
  // about 1e-3, and the band's signs flip with the rounding noise, so the active set never repeats.
  const int m = 31;
  const RowMat A = RowMat(laplacian_2d(m) * 1e8);
  const Eigen::Index n = A.rows();
  Vec z_star = Vec::Zero(n), w_star = Vec::Zero(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const int band = static_cast<int>((i % m) * 3 / m);  // columns: inactive | degenerate | active
    if (band == 0) z_star[i] = 1.0 + 0.01 * static_cast<double>(i % 7);
    if (band == 2) w_star[i] = 1e6;
  }
  const Vec q = w_star - A * z_star;
  Options o;
  o.method = Method::Newton;
  o.tol = 1e-300;
  const Newton<RowMat> newton(A, o);
  const Result r = newton.solve(q);
  Vec t = q.cwiseAbs();
  t += A.cwiseAbs() * r.z.cwiseAbs();
  const double level = std::numeric_limits<double>::epsilon() * (t.norm() + r.z.cwiseAbs().norm());
  CHECK(r.status == Status::Stagnated);
  CHECK(r.iterations <= 5);
  CHECK(r.residual <= 100 * level);
  CHECK((r.z - z_star).lpNorm<Eigen::Infinity>() < 1e-8);
  CHECK(r.message.find("rounding level") != std::string::npos);
  CHECK(r.message.find(to_text(r.residual)) != std::string::npos);
}

TEST_CASE("rtol: the target is max(tol, rtol Res(0)), Res(0) = ||min(q, -zeta(0))||") {
  const RowMat A = laplacian_2d(15);
  const Vec psi = paraboloid(15);
  const Vec q = Vec::Constant(A.rows(), 8.0);  // a downward load onto the obstacle
  const double res0 = q.cwiseMin(-psi).norm();
  for (const double rtol : {1e-2, 1e-6}) {
    Options o;
    o.method = Method::Newton;
    o.tol = 0;
    o.rtol = rtol;
    CHECK(o.target(res0) == doctest::Approx(rtol * res0));
    for (const Method method : {Method::Newton, Method::NRMGS}) {
      o.method = method;
      o.maxiter = 100000;
      const Result r = method == Method::Newton ? Newton<RowMat>(A, o).solve(q, Zeta<int>::constant(psi))
                                                : Solver<RowMat>(A, o).solve(q, Zeta<int>::constant(psi));
      CHECK(r.status == Status::Converged);
      CHECK(r.residual < rtol * res0);
      if (method == Method::NRMGS) CHECK(r.residual > 1e-3 * rtol * res0);  // it stopped there, not at rounding
    }
  }
  Options o;
  o.tol = 1e-3;
  o.rtol = 1e-12;
  CHECK(o.target(res0) == 1e-3);  // the larger of the two
}

namespace {
/// A plain Newton step with scripted trial residuals (the interface detail::Globalized drives):
/// step k tries Res `trials[k]` on the inactive set k (a new set each step, the last one repeated;
/// or `sets[k]`), and records the forcing each solve was given; its trial k has `trial_active[k]`
/// active points (0 if not scripted), and it records the damping factors it was given.
struct ScriptedStep {
  static constexpr bool set_fixes_step = true;
  static constexpr bool smoothing_solves = false;  // (its smoothing: sweeps)
  std::vector<double> trials;
  double level;
  double r;
  std::vector<int> sets = {};
  std::vector<std::size_t> trial_active = {};
  std::vector<double> forcings = {};
  std::vector<double> tols = {};  // the tol each solve was given
  std::vector<double> dampings = {};
  std::vector<int> smoothings = {};
  int k = 0;
  Vec z_ = Vec::Zero(4);
  Eigen::Index size() const { return 4; }
  const Vec& z() const { return z_; }
  double residual() const { return r; }
  int steps() const { return k; }
  int solves() const { return k; }
  long long inner_iterations() const { return 0; }
  void active_set(std::vector<char>& inactive) const {
    const int last = static_cast<int>(trials.size()) - 1;
    const int set = sets.empty() ? std::min(k, last) + 1 : sets[static_cast<std::size_t>(std::min(k, last))];
    inactive.assign(4, 0);
    for (int b = 0; b < 4; ++b) inactive[b] = (set >> b) & 1;
  }
  double modulus(Vec& x) const {  // x ← z; ‖Δx‖∞ (∞ from an empty x), as NewtonStep::modulus
    const double step = x.size() == z_.size() ? (z_ - x).lpNorm<Eigen::Infinity>() : std::numeric_limits<double>::infinity();
    x = z_;
    return step;
  }
  bool linearize() { return true; }
  bool factorize(const std::vector<char>&) { return true; }
  // the active sets' bookkeeping of one process (NewtonStep forwards NewtonLevel's)
  const nrmicp::detail::Comm& comm() const { return nrmicp::detail::serial_comm(); }
  std::uint64_t fingerprint(const std::vector<char>& set) const { return nrmicp::detail::hash_rows(set, 0); }
  bool same_set(const std::vector<char>& a, const std::vector<char>& b) const { return a == b; }
  std::size_t active_count(const std::vector<char>& set) const {
    return set.size() - static_cast<std::size_t>(std::count(set.begin(), set.end(), nrmicp::detail::kInactive));
  }
  double solve(const std::vector<char>&, double tol, double forcing, double = 0) {
    forcings.push_back(forcing);
    tols.push_back(tol);
    return trials[static_cast<std::size_t>(k++)];
  }
  double rounding_level() const { return level; }
  std::size_t trial_active_count() const {
    return static_cast<std::size_t>(k - 1) < trial_active.size() ? trial_active[static_cast<std::size_t>(k - 1)] : 0;
  }
  double damp(double alpha) {
    dampings.push_back(alpha);
    return trials[static_cast<std::size_t>(k - 1)];
  }
  bool smooth(int sweeps) {
    smoothings.push_back(sweeps);
    return false;
  }
  double trial_residual() const { return trials[static_cast<std::size_t>(k - 1)]; }
  bool iterative() const { return true; }
  bool trial_still() const { return false; }
  void accept() {
    r = trials[static_cast<std::size_t>(k - 1)];
    z_.setConstant(static_cast<double>(k));
  }
  double restart(const Vec&) { return r; }
  Result sweep(const Vec&, int, double) { return Result{}; }
};
}  // namespace

TEST_CASE("the rounding-floor stop needs Res at the level after the step too: a step that jumps out of it goes on") {
  // As measured on obstacle_2d m = 1023 (A = Laplacian / h², geometric hierarchy, tol 1e-8): the
  // second step from Res 4.9e-6 (level 2.4e-7, 8 points of the active set wrong) went to 0.68 and
  // the third reached 6.4e-8. The solve stopped after the second, returning 4.9e-6.
  ScriptedStep plain{{4.9e-6, 0.68, 6.4e-8}, 2.4e-7, 1.6e7};
  detail::NewtonControl ctl;
  ctl.solve.tol = 1e-8;
  ctl.solve.maxiter = 10;
  const auto out = detail::newton_loop(plain, ctl, Vec(plain.z()));
  CHECK(out.steps == 3);
  CHECK(out.residual == 6.4e-8);
  CHECK(out.status == Status::Stagnated);  // settled at the floor, above tol
  CHECK(out.message.find("rounding floor") != std::string::npos);

  ScriptedStep at_floor{{4.9e-6, 4.0e-6, 1e-9}, 2.4e-7, 1.6e7};  // stays in the band: a stop at once
  const auto stop = detail::newton_loop(at_floor, ctl, Vec(at_floor.z()));
  CHECK(stop.steps == 2);
  CHECK(stop.residual == 4.0e-6);
}

TEST_CASE("steps on new sets are solved loosely; a repeated set is solved again unless Res is below repeat_trust x its start") {
  detail::NewtonControl ctl;
  ctl.solve.tol = 1e-10;
  ctl.solve.maxiter = 10;
  ctl.first_forcing = 1e-4;
  ctl.forcing = 0.1;
  ctl.repeat_trust = 0;  // the finest level
  // sets 5, 6, 6: the first step at first_forcing, the second (a new set) at forcing, its repeat exact
  ScriptedStep plain{{1e-3, 1e-4, 1e-12}, 1e-14, 1e7, {5, 6, 6}};
  const auto out = detail::newton_loop(plain, ctl, Vec(plain.z()));
  CHECK(out.status == Status::Converged);
  CHECK(out.residual == 1e-12);
  REQUIRE(plain.forcings.size() == 3);
  CHECK(plain.forcings[0] == 1e-4);
  CHECK(plain.forcings[1] == 0.1);
  CHECK(plain.forcings[2] == 0.0);
  // the two steps on new sets are smoothed, the exact solve of the repeated set is kept as solved
  CHECK(plain.smoothings == std::vector<int>{detail::kSmoothingSweeps, detail::kSmoothingSweeps});

  CHECK(plain.tols[2] == 1e-10);  // to tol / 10 (NewtonStep::solve)

  ctl.solve.tol = 0;  // a coarse level: the repeat of a loosely solved set settles once Res < repeat_trust Res(start)
  ctl.repeat_trust = 1e-4;
  ScriptedStep coarse{{1e-3, 1e-4, 1e-12}, 1e-14, 1e7, {5, 6, 6}};
  const auto start = detail::newton_loop(coarse, ctl, Vec(coarse.z()));
  CHECK(start.status == Status::Stagnated);
  CHECK(start.residual == 1e-4);  // 1e-4 < 1e-4 x 1e7
  CHECK(coarse.forcings.size() == 2);
  // Res barely below the start's (a loose solve that did not move z enough to show the set): the
  // repeat is solved again, to max(tol, repeat_trust Res(start)), and its new set goes on
  ScriptedStep slow{{1e6, 1e5, 1e2, 1.0}, 1e-14, 1e7, {5, 5, 6, 6}};
  const auto went_on = detail::newton_loop(slow, ctl, Vec(slow.z()));
  CHECK(went_on.status == Status::Stagnated);
  CHECK(went_on.residual == 1e2);
  CHECK(slow.forcings == std::vector<double>{1e-4, 0.0, 0.1});
  CHECK(slow.tols[1] == 1e3);
  ctl.repeat_trust = std::numeric_limits<double>::infinity();  // every repeat settles
  ScriptedStep trusting{{1e6, 1e5}, 1e-14, 1e7, {5, 5}};
  CHECK(detail::newton_loop(trusting, ctl, Vec(trusting.z())).residual == 1e6);
  CHECK(trusting.forcings.size() == 1);
  ctl.solve.tol = 1e-10;

  ctl.repeat_trust = 0;  // exact steps (forcing 0) whose set repeats: settled, no second solve
  ctl.first_forcing = ctl.forcing = 0;
  ScriptedStep exact{{1e-3, 1e-12}, 1e-14, 1e7, {5, 5}};
  const auto settled = detail::newton_loop(exact, ctl, Vec(exact.z()));
  CHECK(settled.status == Status::Stagnated);
  CHECK(exact.forcings.size() == 1);
}

TEST_CASE("a step whose active set more than triples the one it was solved on is damped once by half") {
  detail::NewtonControl ctl;
  ctl.solve.tol = 1e-10;
  ctl.solve.maxiter = 10;
  // sets 14, 12, 8: 1, 2, 3 active points (bits = inactive); the trials have 4, 6, 3 active points
  ScriptedStep plain{{1e-3, 1e-6, 1e-12}, 1e-14, 1e7, {14, 12, 8}, {4, 6, 3}};
  const auto out = detail::newton_loop(plain, ctl, Vec(plain.z()));
  CHECK(out.status == Status::Converged);
  REQUIRE(plain.dampings.size() == 1);  // 4 > 3 x 1: damped; 6 = 3 x 2 and 3 < 3 x 3: not
  CHECK(plain.dampings[0] == detail::kOvershootDamping);

  ScriptedStep from_empty{{1e-3, 1e-12}, 1e-14, 1e7, {15, 14}, {4, 1}};  // no active point: no ratio
  detail::newton_loop(from_empty, ctl, Vec(from_empty.z()));
  CHECK(from_empty.dampings.empty());
}

TEST_CASE("projected Gauss-Seidel sweeps keep y >= 0, leave the LCP's solution in place and converge to it") {
  const RowMat A = testing::bai<int, Eigen::RowMajor>(6, 0.0, true);  // the 5-point Laplacian: an M-matrix
  const auto n = A.rows();
  const auto k = testing::known_solution(n);
  const Vec q = k.w - A * k.g;  // LCP(q, A) has the solution z = g (w = Az + q, z ⊥ w)
  const detail::NewtonLevel<RowMat> level(A, Options());
  Vec y = k.g;
  level.projected_gauss_seidel(q, y, 3);
  CHECK((y - k.g).lpNorm<Eigen::Infinity>() < 1e-13);  // a fixed point
  y = Vec::Constant(n, 5.0);
  level.projected_gauss_seidel(q, y, 1);
  CHECK(y.minCoeff() >= 0.0);
  level.projected_gauss_seidel(q, y, 400);
  CHECK((y - k.g).lpNorm<Eigen::Infinity>() < 1e-8);
}

TEST_CASE("a row with a non-positive diagonal is left by the projected sweep") {
  Eigen::MatrixXd D(2, 2);
  D << 0.0, 1.0, -1.0, 2.0;
  const RowMat A = D.sparseView();
  Options o;
  o.omega2 = Vec::Ones(2);  // Newton's own Ω2 needs no positive diagonal
  const detail::NewtonLevel<RowMat> level(A, o);
  Vec y(2);
  y << 0.7, 0.3;
  const Vec q = Vec::Constant(2, -1.0);
  level.projected_gauss_seidel(q, y, 1);
  CHECK(y[0] == 0.7);                                        // a_00 = 0: left
  CHECK(y[1] == doctest::Approx((1.0 + 0.7) / 2.0));  // max(0, -(q_1 + a_10 y_0) / a_11), both sweeps
}
