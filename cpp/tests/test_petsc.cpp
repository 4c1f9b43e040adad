// The Newton member from C++ on the PETSc engine (nrmicp/petsc.hpp), run by ctest under mpiexec on
// 1 and 2 processes: the same nrmicp::Newton over a distributed Mat takes the serial member's
// decisions (status, finest steps within 1, z to 1e-8) and its answer meets the complementarity
// conditions row by row — a 2D obstacle cold and nested (bilinear prolongations), a two-sided box, and
// the 'amg' hierarchy built from A alone (nrmicp/petsc/hierarchy.hpp) on a 2D and a 3D obstacle; and
// the engine's own parts that split rows between processes: the Galerkin operators' update by K's
// changed entries (against P_lᵀ⋯KP_l computed here), the symmetry check (against the serial rule),
// |A| v (against the dense product), and input one process gets wrong refused on every process.
#include "common.hpp"

#include <nrmicp/petsc.hpp>

#define DOCTEST_CONFIG_IMPLEMENT
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <vector>

using namespace nrmicp;

namespace {
using RowMat = testing::SpMat<int, Eigen::RowMajor>;
using Vec = Eigen::VectorXd;

int rank_of() { int r = 0; MPI_Comm_rank(PETSC_COMM_WORLD, &r); return r; }
int size_of() { int s = 1; MPI_Comm_size(PETSC_COMM_WORLD, &s); return s; }

/// [lo, hi) of this process among n rows (contiguous blocks, PETSc's split).
std::pair<int, int> split(int n) {
  const int p = size_of(), r = rank_of(), base = n / p, extra = n % p;
  const int lo = r * base + std::min(r, extra);
  return {lo, lo + base + (r < extra ? 1 : 0)};
}

/// B's rows [lo, hi) as a distributed AIJ Mat (columns split as `cols` would be).
Mat to_petsc(const RowMat& B) {
  const auto [lo, hi] = split(static_cast<int>(B.rows()));
  const auto [clo, chi] = split(static_cast<int>(B.cols()));
  std::vector<PetscInt> ia{0}, ja;
  std::vector<PetscScalar> va;
  for (int i = lo; i < hi; ++i) {
    for (RowMat::InnerIterator it(B, i); it; ++it) { ja.push_back(it.index()); va.push_back(it.value()); }
    ia.push_back(static_cast<PetscInt>(ja.size()));
  }
  Mat M;
  REQUIRE(MatCreate(PETSC_COMM_WORLD, &M) == 0);
  REQUIRE(MatSetSizes(M, hi - lo, chi - clo, B.rows(), B.cols()) == 0);
  REQUIRE(MatSetType(M, MATAIJ) == 0);
  REQUIRE(MatSeqAIJSetPreallocationCSR(M, ia.data(), ja.data(), va.data()) == 0);  // the one of M's type acts
  REQUIRE(MatMPIAIJSetPreallocationCSR(M, ia.data(), ja.data(), va.data()) == 0);
  REQUIRE(MatAssemblyBegin(M, MAT_FINAL_ASSEMBLY) == 0);
  REQUIRE(MatAssemblyEnd(M, MAT_FINAL_ASSEMBLY) == 0);
  return M;
}

Vec rows_of(const Vec& v) {
  const auto [lo, hi] = split(static_cast<int>(v.size()));
  return v.segment(lo, hi - lo);
}

/// The 5-point −Δ_h on the m × m interior grid of (0, 1)², h = 1/(m + 1).
RowMat laplacian(int m) {
  const double h2 = 1.0 / ((m + 1.0) * (m + 1.0));
  std::vector<Eigen::Triplet<double>> t;
  for (int j = 0; j < m; ++j)
    for (int i = 0; i < m; ++i) {
      const int r = j * m + i;
      t.emplace_back(r, r, 4.0 / h2);
      if (i > 0) t.emplace_back(r, r - 1, -1.0 / h2);
      if (i + 1 < m) t.emplace_back(r, r + 1, -1.0 / h2);
      if (j > 0) t.emplace_back(r, r - m, -1.0 / h2);
      if (j + 1 < m) t.emplace_back(r, r + m, -1.0 / h2);
    }
  RowMat A(m * m, m * m);
  A.setFromTriplets(t.begin(), t.end());
  return A;
}

/// Bilinear interpolation from the (m − 1)/2 grid to the m grid (m odd), 2D.
RowMat bilinear(int m) {
  const int mc = (m - 1) / 2;
  std::vector<Eigen::Triplet<double>> t;
  for (int J = 0; J < mc; ++J)
    for (int I = 0; I < mc; ++I)
      for (int dj = -1; dj <= 1; ++dj)
        for (int di = -1; di <= 1; ++di) {
          const int i = 2 * I + 1 + di, j = 2 * J + 1 + dj;
          t.emplace_back(j * m + i, J * mc + I, (di ? 0.5 : 1.0) * (dj ? 0.5 : 1.0));
        }
  RowMat P(m * m, mc * mc);
  P.setFromTriplets(t.begin(), t.end());
  return P;
}

struct Case {
  RowMat A;
  Vec q, lower, upper;  // upper empty: one-sided
  std::vector<RowMat> P;
};

/// A membrane over ψ = 0.1 − |x − ½|² under the load f (and below ψ + 0.15 when two-sided).
Case membrane(int m, double f, bool two_sided, int levels) {
  Case c{laplacian(m), Vec(m * m), Vec(m * m), Vec(), {}};
  const double h = 1.0 / (m + 1.0);
  for (int j = 0; j < m; ++j)
    for (int i = 0; i < m; ++i) {
      const double x = (i + 1) * h - 0.5, y = (j + 1) * h - 0.5;
      c.lower[j * m + i] = 0.1 - x * x - y * y;
      c.q[j * m + i] = -f * (x > 0 ? 1.0 : -1.0);
    }
  if (two_sided) c.upper = c.lower.array() + 0.15;
  for (int l = 0, k = m; l < levels; ++l, k = (k - 1) / 2) c.P.push_back(bilinear(k));
  return c;
}

/// The MCP conditions at z (this process's rows): lower ≤ z ≤ upper, w ≥ 0 at lower, ≤ 0 at upper, 0 between.
void check_conditions(const Case& c, const Vec& z_all, double tol) {
  const Vec w = c.A * z_all + c.q;
  const auto [lo, hi] = split(static_cast<int>(z_all.size()));
  const double scale = tol * (1.0 + w.cwiseAbs().maxCoeff());
  for (int i = lo; i < hi; ++i) {
    const double up = c.upper.size() ? c.upper[i] : HUGE_VAL;
    CHECK(z_all[i] >= c.lower[i] - tol);
    CHECK(z_all[i] <= up + tol);
    const bool at_lower = z_all[i] - c.lower[i] <= 1e-9, at_upper = up - z_all[i] <= 1e-9;
    if (!at_lower && !at_upper) CHECK(std::abs(w[i]) <= scale);
    if (at_lower && !at_upper) CHECK(w[i] >= -scale);
    if (at_upper && !at_lower) CHECK(w[i] <= scale);
  }
}

/// Every process's rows of v, on every process.
Vec gather(const Vec& local, Eigen::Index n) {
  const int p = size_of();
  std::vector<int> counts(p), displs(p);
  const int mine = static_cast<int>(local.size());
  MPI_Allgather(&mine, 1, MPI_INT, counts.data(), 1, MPI_INT, PETSC_COMM_WORLD);
  for (int r = 1; r < p; ++r) displs[r] = displs[r - 1] + counts[r - 1];
  Vec all(n);
  MPI_Allgatherv(local.data(), mine, MPI_DOUBLE, all.data(), counts.data(), displs.data(), MPI_DOUBLE, PETSC_COMM_WORLD);
  return all;
}

/// The default options with `method` (and `tol`, when given).
Options with_method(Method method, double tol = -1) {
  Options o;
  o.method = method;
  if (tol > 0) o.tol = tol;
  return o;
}

void run(const Case& c, const char* what) {
  INFO(what << " on " << size_of() << " processes");
  const Options o = with_method(Method::Newton, 1e-9);
  Zeta<int> zs = Zeta<int>::constant(c.lower);
  if (c.upper.size()) zs = zs.with_upper(c.upper);
  const Result serial = Newton<RowMat>(c.A, o, c.P).solve(c.q, zs);

  Mat A = to_petsc(c.A);
  std::vector<petsc::Matrix> P;
  for (const RowMat& p : c.P) {
    Mat M = to_petsc(p);
    P.emplace_back(M);
    MatDestroy(&M);  // the engine's Matrix holds its own reference
  }
  Result r;
  {
    const petsc::Matrix Am(A);
    Zeta<PetscInt> zd = Zeta<PetscInt>::constant(rows_of(c.lower));
    if (c.upper.size()) zd = zd.with_upper(rows_of(c.upper));
    r = Newton<petsc::Matrix>(Am, o, P).solve(rows_of(c.q), zd);
  }
  MatDestroy(&A);
  const Vec z = gather(r.z, c.A.rows());
  CHECK(serial.status == Status::Converged);
  CHECK(r.status == serial.status);
  CHECK(r.residual < 1e-9);
  REQUIRE(r.newton.level_steps.size() == serial.newton.level_steps.size());
  CHECK(std::abs(r.newton.level_steps[0] - serial.newton.level_steps[0]) <= 1);
  CHECK((z - serial.z).lpNorm<Eigen::Infinity>() <= 1e-8 * serial.z.lpNorm<Eigen::Infinity>());
  check_conditions(c, z, 1e-8);
}
/// The 7-point −Δ_h on the m³ interior grid of (0, 1)³ and the obstacle ψ = 0.1 − |x − ½|² (no load).
Case obstacle_3d(int m) {
  const double h = 1.0 / (m + 1.0), h2 = h * h;
  const int n = m * m * m;
  std::vector<Eigen::Triplet<double>> t;
  Case c{RowMat(n, n), Vec::Zero(n), Vec(n), Vec(), {}};
  for (int k = 0; k < m; ++k)
    for (int j = 0; j < m; ++j)
      for (int i = 0; i < m; ++i) {
        const int r = (k * m + j) * m + i;
        const double x = (i + 1) * h - 0.5, y = (j + 1) * h - 0.5, w = (k + 1) * h - 0.5;
        c.lower[r] = 0.1 - x * x - y * y - w * w;
        t.emplace_back(r, r, 6.0 / h2);
        const int step[3] = {1, m, m * m}, at[3] = {i, j, k};
        for (int d = 0; d < 3; ++d) {
          if (at[d] > 0) t.emplace_back(r, r - step[d], -1.0 / h2);
          if (at[d] + 1 < m) t.emplace_back(r, r + step[d], -1.0 / h2);
        }
      }
  c.A.setFromTriplets(t.begin(), t.end());
  return c;
}

/// ‖C − PᵀAP‖_F / ‖C‖_F (PETSc's PtAP, an independent product).
double galerkin_defect(Mat A, Mat P, Mat C) {
  Mat G;
  REQUIRE(MatPtAP(A, P, MAT_INITIAL_MATRIX, 2.0, &G) == 0);
  PetscReal nc = 0, nd = 0;
  MatNorm(C, NORM_FROBENIUS, &nc);
  REQUIRE(MatAXPY(G, -1.0, C, DIFFERENT_NONZERO_PATTERN) == 0);
  MatNorm(G, NORM_FROBENIUS, &nd);
  MatDestroy(&G);
  return nd / nc;
}

/// Whether the options database holds an option whose name starts with -nrmicp.
bool options_left() {
  char* all = nullptr;
  PetscOptionsGetAll(nullptr, &all);
  const bool left = all && std::strstr(all, "-nrmicp");
  PetscFree(all);
  return left;
}

/// The 'amg' hierarchy (nrmicp/petsc/hierarchy.hpp) from A alone: Galerkin levels, the first no denser
/// than kFoldDensity × A, nothing left in the options database; the Newton member nested over it meets
/// the complementarity conditions and the serial cold solve's z, in few finest steps.
void run_amg(const Case& c, const char* what) {
  INFO(what << " on " << size_of() << " processes");
  const Options o = with_method(Method::Newton, 1e-9);
  const Result serial = Newton<RowMat>(c.A, o).solve(c.q, Zeta<int>::constant(c.lower));
  Mat A = to_petsc(c.A);
  Result r;
  {
    const petsc::Matrix Am(A);
    const petsc::AmgHierarchy h = petsc::amg_hierarchy(Am);
    CHECK_FALSE(options_left());
    REQUIRE(h.prolongations.size() >= 2);
    REQUIRE(h.coarse_operators.size() == h.prolongations.size());
    CHECK(static_cast<double>(petsc::global_nonzeros(h.coarse_operators[0].get())) <=
          petsc::kFoldDensity * static_cast<double>(c.A.nonZeros()));
    Mat finer = A;
    for (std::size_t l = 0; l < h.prolongations.size(); ++l) {
      CHECK(galerkin_defect(finer, h.prolongations[l].get(), h.coarse_operators[l].get()) < 1e-12);
      finer = h.coarse_operators[l].get();
    }
    r = Newton<petsc::Matrix>(Am, o, h.prolongations, h.coarse_operators).solve(rows_of(c.q),
                                                                                Zeta<PetscInt>::constant(rows_of(c.lower)));
  }
  MatDestroy(&A);
  const Vec z = gather(r.z, c.A.rows());
  CHECK(r.status == Status::Converged);
  CHECK(r.residual < 1e-9);
  CHECK(r.newton.level_steps.size() > 2);
  CHECK(r.newton.level_steps[0] <= 5);
  CHECK((z - serial.z).lpNorm<Eigen::Infinity>() <= 1e-8 * serial.z.lpNorm<Eigen::Infinity>());
  check_conditions(c, z, 1e-8);
}
}  // namespace

TEST_CASE("the 'amg' hierarchy from A alone: 2D obstacle (a classical first level)") {
  run_amg(membrane(63, 0.0, false, 0), "amg 2D");
}

TEST_CASE("the 'amg' hierarchy from A alone: 3D obstacle (a dense first level folded)") {
  run_amg(obstacle_3d(15), "amg 3D");
}

TEST_CASE("the Newton member on PETSc takes the serial decisions: obstacle cold") {
  run(membrane(31, 0.0, false, 0), "obstacle cold");
}

TEST_CASE("the Newton member on PETSc takes the serial decisions: obstacle nested") {
  run(membrane(63, 0.0, false, 3), "obstacle nested");
}

TEST_CASE("the Newton member on PETSc takes the serial decisions: two-sided box, nested") {
  run(membrane(63, 20.0, true, 3), "two-sided nested");
}

namespace {
/// This process's rows of a Mat against the same rows of a dense reference: max |M − ref| over every
/// process, relative to max |ref| (an entry of ref that M does not store counts in full).
double relative_difference(Mat M, const Eigen::MatrixXd& ref) {
  PetscInt lo, hi;
  MatGetOwnershipRange(M, &lo, &hi);
  double d[2] = {0, ref.cwiseAbs().maxCoeff()};
  for (PetscInt i = lo; i < hi; ++i) {
    Eigen::RowVectorXd row = ref.row(i);
    PetscInt k;
    const PetscInt* cols;
    const PetscScalar* vals;
    MatGetRow(M, i, &k, &cols, &vals);
    for (PetscInt p = 0; p < k; ++p) row[cols[p]] -= vals[p];
    MatRestoreRow(M, i, &k, &cols, &vals);
    d[0] = std::max(d[0], row.cwiseAbs().maxCoeff());
  }
  MPI_Allreduce(MPI_IN_PLACE, d, 2, MPI_DOUBLE, MPI_MAX, PETSC_COMM_WORLD);
  return d[0] / d[1];
}

/// K(i, j) += v on the Mat (its owner's call) and on the serial copy, (i, j) stored in both.
void add_entry(Mat K, RowMat& Ks, int i, int j, double v) {
  Ks.coeffRef(i, j) += v;
  PetscInt lo, hi;
  MatGetOwnershipRange(K, &lo, &hi);
  if (i >= lo && i < hi) MatSetValue(K, i, j, v, ADD_VALUES);
}

/// The Galerkin chain P_lᵀ ⋯ P_0ᵀ K P_0 ⋯ P_l computed here (Eigen, dense coarse levels), and the
/// engine's operators checked against it.
void check_operators(const petsc::GalerkinOperators& G, const RowMat& K, const std::vector<RowMat>& P) {
  Eigen::MatrixXd C = Eigen::MatrixXd(K);
  for (std::size_t l = 0; l < P.size(); ++l) {
    const Eigen::MatrixXd Pl = Eigen::MatrixXd(P[l]);
    C = Pl.transpose() * C * Pl;
    CHECK(relative_difference(G.K(l), C) <= 1e-13);
  }
}
}  // namespace

namespace {
/// A nonsymmetric K on a 2D grid (the upwind part couples rows held by different processes) and
/// three bilinear prolongations.
struct GalerkinCase {
  using Changes = petsc::GalerkinOperators::Changes;
  int m = 31, n = 31 * 31;
  RowMat K = laplacian(31);
  std::vector<RowMat> P{bilinear(31), bilinear(15), bilinear(7)};
  GalerkinCase() {
    for (int r = m; r < n; ++r) K.coeffRef(r, r - m) -= 0.3 * (m + 1.0) * (m + 1.0);
  }
  /// A few changed entries, several of them coupling rows on both sides of the processes' split;
  /// returns them (this process's rows).
  Changes change_few(Mat Km) {
    const RowMat before = K;
    const int mid = n / 2;
    const int at[][2] = {{mid, mid}, {mid - 1, mid}, {mid, mid - 1}, {mid - 1, mid - 1 + m}, {mid + 2, mid + 2 - m}, {5, 6}};
    for (int k = 0; k < 6; ++k) add_entry(Km, K, at[k][0], at[k][1], 0.37 * (k + 1) * (m + 1.0) * (m + 1.0));
    MatAssemblyBegin(Km, MAT_FINAL_ASSEMBLY);
    MatAssemblyEnd(Km, MAT_FINAL_ASSEMBLY);
    return changes_since(before);
  }
  /// Every entry changed (K scaled).
  Changes change_all(Mat Km) {
    const RowMat before = K;
    MatScale(Km, 1.5);
    K *= 1.5;
    return changes_since(before);
  }
  /// K − before on this process's rows (K keeps before's pattern).
  Changes changes_since(const RowMat& before) const {
    Changes c;
    const auto [lo, hi] = split(n);
    for (int i = lo; i < hi; ++i)
      for (RowMat::InnerIterator a(before, i), b(K, i); a && b; ++a, ++b)
        if (a.value() != b.value()) c.push_back({i, static_cast<PetscInt>(a.index()), b.value() - a.value()});
    return c;
  }
  /// P_lᵀ ⋯ K ⋯ P_l of the current K, level by level (Eigen, as a hierarchy's operators would be).
  std::vector<RowMat> chain() const {
    std::vector<RowMat> C;
    RowMat F = K;
    for (const RowMat& p : P) {
      RowMat c = RowMat(p.transpose()) * F * p;
      C.push_back(c);
      F = c;
    }
    return C;
  }
};

void destroy(std::vector<Mat>& Ms) {
  for (Mat& M : Ms) MatDestroy(&M);
}
}  // namespace

TEST_CASE("the PETSc engine's Galerkin operators follow K's changed entries: updated as recomputed") {
  INFO("on " << size_of() << " processes");
  GalerkinCase c;
  Mat K = to_petsc(c.K);
  std::vector<Mat> Pm;
  for (const RowMat& p : c.P) Pm.push_back(to_petsc(p));
  {
    petsc::GalerkinOperators G(Pm);
    const GalerkinCase::Changes none;
    CHECK(G.form(K, &none));  // formed (MatPtAP)
    CHECK_FALSE(G.updated());
    check_operators(G, c.K, c.P);
    GalerkinCase::Changes changes = c.change_few(K);
    CHECK_FALSE(G.form(K, &changes));
    CHECK(G.updated());
    check_operators(G, c.K, c.P);
    changes = c.change_all(K);  // too many changed entries: recomputed
    G.form(K, &changes);
    CHECK_FALSE(G.updated());
    check_operators(G, c.K, c.P);
    changes = c.change_few(K);  // not recorded: recomputed
    G.form(K, nullptr);
    CHECK_FALSE(G.updated());
    check_operators(G, c.K, c.P);
  }
  destroy(Pm);
  MatDestroy(&K);
}

TEST_CASE("the PETSc engine's Galerkin operators start from the hierarchy's: updated by K - A, or formed") {
  INFO("on " << size_of() << " processes");
  for (bool few : {true, false}) {
    INFO((few ? "few changes" : "every entry changed"));
    GalerkinCase c;
    Mat A = to_petsc(c.K), K = to_petsc(c.K);
    std::vector<Mat> Pm, coarse;
    for (const RowMat& p : c.P) Pm.push_back(to_petsc(p));
    for (const RowMat& C : c.chain()) coarse.push_back(to_petsc(C));
    GalerkinCase::Changes changes = few ? c.change_few(K) : c.change_all(K);
    {
      petsc::GalerkinOperators G(Pm, A, coarse);
      CHECK(G.form(K, &changes));   // new Mats either way
      CHECK(G.updated() == few);    // copies of the hierarchy's updated, or MatPtAP's
      check_operators(G, c.K, c.P);
      changes = c.change_few(K);
      CHECK_FALSE(G.form(K, &changes));
      CHECK(G.updated());
      check_operators(G, c.K, c.P);
      changes = c.change_all(K);
      CHECK(G.form(K, &changes) == few);  // the hierarchy's copies give way to new Mats (PCMG takes them)
      CHECK_FALSE(G.updated());
      check_operators(G, c.K, c.P);
      changes = c.change_all(K);
      CHECK_FALSE(G.form(K, &changes));   // MatPtAP's own Mats: values recomputed in place
      check_operators(G, c.K, c.P);
    }
    destroy(Pm);
    destroy(coarse);
    MatDestroy(&A);
    MatDestroy(&K);
  }
}

TEST_CASE("the PETSc engine's symmetry check is the serial rule: ||M - M^T||_F <= 1e-14 ||M||_F") {
  INFO("on " << size_of() << " processes");
  const int m = 15, n = m * m, i = n / 2, j = n / 2 + m;  // (i, j): rows on both sides of the split
  const RowMat L = laplacian(m);
  const double threshold = 1e-14 * L.norm() / std::sqrt(2.0);  // one entry off by this: at the bound
  for (double off : {0.0, 0.5 * threshold, 2 * threshold}) {
    RowMat M = L;
    M.coeffRef(i, j) += off;
    const Eigen::MatrixXd D = Eigen::MatrixXd(M);
    const bool expected = (D - D.transpose()).norm() <= 1e-14 * D.norm();
    CHECK(expected == (off < threshold));
    Mat A = to_petsc(M);
    CHECK(petsc::is_symmetric(A) == expected);
    MatDestroy(&A);
  }
  // an entry whose mirror is not stored: symmetric when it is 0, not when it is not
  for (double v : {0.0, 1.0}) {
    RowMat M = L;
    M.insert(3, n - 2) = v;
    M.makeCompressed();
    Mat A = to_petsc(M);
    CHECK(petsc::is_symmetric(A) == (v == 0.0));
    MatDestroy(&A);
  }
}

TEST_CASE("the PETSc engine's |A| v adds every row's |a_ij| v_j, the other processes' columns included") {
  INFO("on " << size_of() << " processes");
  const int m = 15, n = m * m;
  RowMat Ks = laplacian(m);
  for (int r = m; r < n; ++r) Ks.coeffRef(r, r - m) -= 3.0;  // nonsymmetric, some entries change sign
  Ks.coeffRef(2, n - 3) = -7.0;                              // a coupling to the last rows
  Ks.makeCompressed();
  Eigen::VectorXd v(n), start(n);
  for (int i = 0; i < n; ++i) { v[i] = std::sin(1.0 + i); start[i] = std::cos(2.0 * i); }
  const Eigen::VectorXd expected = start + Eigen::MatrixXd(Ks).cwiseAbs() * v;
  Mat K = to_petsc(Ks);
  {
    const petsc::Matrix A(K);
    Eigen::VectorXd out = rows_of(start);
    abs_multiply_add(A, rows_of(v), out);
    CHECK((out - rows_of(expected)).lpNorm<Eigen::Infinity>() <= 1e-12 * expected.lpNorm<Eigen::Infinity>());
    out = rows_of(start);
    abs_multiply_add(A, rows_of(v), out);  // (the gather of the other processes' columns, formed once, again)
    CHECK((out - rows_of(expected)).lpNorm<Eigen::Infinity>() <= 1e-12 * expected.lpNorm<Eigen::Infinity>());
  }
  MatDestroy(&K);
}

/// B with process 0's and 1's last and first rows moved by `shift` (columns too when `columns`): a square
/// Mat whose row and column layouts differ there, or with every row on process 0 (shift: all of 1's).
Mat shifted_rows(const RowMat& B, int shift, bool columns = false) {
  auto [lo, hi] = split(static_cast<int>(B.rows()));
  auto [clo, chi] = split(static_cast<int>(B.cols()));
  if (rank_of() == 0) hi += shift, chi += columns ? shift : 0;
  if (rank_of() == 1) lo += shift, clo += columns ? shift : 0;
  Mat M;
  REQUIRE(MatCreateAIJ(PETSC_COMM_WORLD, hi - lo, chi - clo, B.rows(), B.cols(), 8, nullptr, 8, nullptr, &M) == 0);
  for (int i = lo; i < hi; ++i)
    for (RowMat::InnerIterator it(B, i); it; ++it) {
      const PetscInt r = i, col = static_cast<PetscInt>(it.index());
      const PetscScalar v = it.value();
      REQUIRE(MatSetValues(M, 1, &r, 1, &col, &v, INSERT_VALUES) == 0);
    }
  REQUIRE(MatAssemblyBegin(M, MAT_FINAL_ASSEMBLY) == 0);
  REQUIRE(MatAssemblyEnd(M, MAT_FINAL_ASSEMBLY) == 0);
  return M;
}

TEST_CASE("an input one process alone gets wrong is refused on every process (none is left waiting)") {
  INFO("on " << size_of() << " processes");
  const Case c = membrane(15, 20.0, false, 0);
  const Options newton_options = with_method(Method::Newton), nrmgs_options = with_method(Method::NRMGS);
  Mat A = to_petsc(c.A);
  {
    const petsc::Matrix Am(A);
    Eigen::VectorXd q = rows_of(c.q);
    if (rank_of() == 0) q.conservativeResize(q.size() - 1);  // one row short on process 0 only
    CHECK_THROWS_AS(Newton<petsc::Matrix>(Am, newton_options).solve(q), std::invalid_argument);
    CHECK_THROWS_AS(Solver<petsc::Matrix>(Am, nrmgs_options).solve(q), std::invalid_argument);
    const Result r = Newton<petsc::Matrix>(Am, newton_options).solve(rows_of(c.q));  // and every process goes on
    CHECK(r.status == Status::Converged);
  }
  MatDestroy(&A);
  RowMat Z = c.A;
  Z.coeffRef(Z.rows() - 1, Z.rows() - 1) = 0.0;  // a zero diagonal in the last process's rows: Ω2 = diag(A) refuses it
  Mat D = to_petsc(Z);
  {
    const petsc::Matrix Dm(D);
    CHECK_THROWS_AS(Solver<petsc::Matrix>(Dm, nrmgs_options), std::invalid_argument);
    // the engine's own rule (petsc::check_operator), for the Newton member too: its smoothers divide by a_ii
    const std::string row = std::to_string(Z.rows() - 1), own = "A[" + row + ", " + row + "] = 0";
    try {
      Newton<petsc::Matrix> refused(Dm, newton_options);
      CHECK(false);
    } catch (const std::invalid_argument& e) {
      const std::string what = e.what();
      CHECK((rank_of() == size_of() - 1 ? what.find(own) : what.find("another process")) != std::string::npos);
    }
  }
  MatDestroy(&D);
  if (size_of() < 2) return;
  Mat B = shifted_rows(c.A, 1);  // process 0 owns a row more than columns, process 1 one fewer
  {
    const petsc::Matrix Bm(B);
    const auto layout = doctest::Contains(rank_of() < 2 ? "create A with the same row and column layout"  // (check_layout)
                                                        : "another process refused");
    CHECK_THROWS_WITH_AS(Newton<petsc::Matrix>(Bm, newton_options), layout, std::invalid_argument);
    CHECK_THROWS_WITH_AS(Solver<petsc::Matrix>(Bm, nrmgs_options), layout, std::invalid_argument);
  }
  MatDestroy(&B);
  if (size_of() != 2) return;
  const int rows_of_1 = split(static_cast<int>(c.A.rows())).second - split(static_cast<int>(c.A.rows())).first;
  int shift = rows_of_1;  // process 1's row count, known to process 0 too (even split, n odd: 0 owns one more)
  if (rank_of() == 0) shift = static_cast<int>(c.A.rows()) / 2;
  Mat C = shifted_rows(c.A, shift, true);  // every row on process 0: the Newton member refuses it on both
  {
    const petsc::Matrix Cm(C);
    CHECK_THROWS_AS(Newton<petsc::Matrix>(Cm, newton_options), std::invalid_argument);
  }
  MatDestroy(&C);
}

TEST_CASE("bounds on one process's rows only (an upper bound, a free row) are every process's problem") {
  INFO("on " << size_of() << " processes");
  Case c = membrane(31, 20.0, true, 2);
  const Eigen::Index n = c.A.rows();
  c.upper.tail(n - n / 3).setConstant(HUGE_VAL);  // bounded above on the first third (process 0's) only
  c.lower[5] = -HUGE_VAL;                          // and free below on row 5 (process 0's)
  const int lo = split(static_cast<int>(n)).first;
  const bool own_upper = lo < n / 3;
  const Result serial = Newton<RowMat>(c.A, with_method(Method::Newton, 1e-9), c.P).solve(
      c.q, Zeta<int>::constant(c.lower).with_upper(c.upper));
  REQUIRE(serial.status == Status::Converged);
  Mat A = to_petsc(c.A);
  std::vector<petsc::Matrix> P;
  for (const RowMat& p : c.P) {
    Mat M = to_petsc(p);
    P.emplace_back(M);
    MatDestroy(&M);
  }
  {
    const petsc::Matrix Am(A);
    Zeta<PetscInt> zd = Zeta<PetscInt>::constant(rows_of(c.lower));
    if (own_upper) zd = zd.with_upper(rows_of(c.upper));  // the other processes pass none
    if (size_of() > 1) CHECK(zd.bounded() == (rank_of() == 0));  // process 1 passes an unbounded zeta
    for (const Method m : {Method::Newton, Method::NRMGS}) {
      INFO("method " << (m == Method::Newton ? "newton" : "nrmgs"));
      const Result r = m == Method::Newton ? Newton<petsc::Matrix>(Am, with_method(m, 1e-9), P).solve(rows_of(c.q), zd)
                                           : Solver<petsc::Matrix>(Am, with_method(m, 1e-9)).solve(rows_of(c.q), zd);
      CHECK(r.status == Status::Converged);
      const Eigen::VectorXd z = gather(r.z, n);
      CHECK((z - serial.z).lpNorm<Eigen::Infinity>() <= 1e-6 * serial.z.lpNorm<Eigen::Infinity>());
      check_conditions(c, z, 1e-6);
    }
  }
  MatDestroy(&A);
}

TEST_CASE("an option the PETSc engine cannot apply to a member is refused naming it (the option table's column)") {
  const Case c = membrane(7, 20.0, false, 0);
  Mat A = to_petsc(c.A);
  {
    const petsc::Matrix Am(A);
    Options o = with_method(Method::Newton);
    o.inner = Inner::CG;  // the Newton member's reduced solves are the engine's (KSP)
    try {
      Newton<petsc::Matrix> refused(Am, o);
      CHECK(false);
    } catch (const std::invalid_argument& e) {
      CHECK(std::string(e.what()).find("inner cannot apply to method 'newton'") != std::string::npos);
    }
    o.method = Method::NRM;  // the stationary members take it (each process's block factorized its way)
    o.inner = Inner::EigenLU;
    CHECK_NOTHROW(Solver<petsc::Matrix>(Am, o));
  }
  MatDestroy(&A);
}

// Its own main: doctest runs between PetscInitialize and PetscFinalize (MPI's lifetime).
int main(int argc, char** argv) {
  if (PetscInitialize(&argc, &argv, nullptr, nullptr)) return 1;
  doctest::Context context(argc, argv);
  const int failed = context.run();
  PetscFinalize();
  return failed;
}
