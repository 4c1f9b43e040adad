// nrmicp — the iterative inner solve of the Newton member (inner = "cg"): a Krylov method on the
// reduced system K of one Newton step (detail/active_set.hpp), preconditioned by one multigrid
// V-cycle built from the same prolongations P_0, P_1, ... the nested iteration uses: conjugate
// gradients when K is symmetric positive definite, else BiCGSTAB (Eigen's).
//
// Per Newton step (setup): the Galerkin operators K_{l+1} = P_lᵀ K_l P_l of the reduced system
// (K changes with the active set, so they are recomputed) and a direct factorization of the
// coarsest one. The V-cycle smooths with one forward Gauss–Seidel sweep before the coarse
// correction and one backward sweep after it: a symmetric preconditioner, positive definite for
// symmetric positive definite K, so CG applies. K's active rows are identity rows with zeroed
// columns (the LCP): K stays SPD when A is, and so does every PᵀKP of full-rank P.
//
// A nonsymmetric K (a nonsymmetric A, or an affine ζ: active rows I − B) is read through a
// row-major copy on a fixed pattern (values only per step) for the Gauss–Seidel sweeps, the
// products and the Galerkin operators Pᵀ K P; the V-cycle is the same, a nonsymmetric
// preconditioner then, and BiCGSTAB replaces CG.
//
// Why BiCGSTAB rather than GMRES: no Krylov basis to store, and its residual is the true one, which
// the absolute target of solve() is about (docs/MEASUREMENTS.md, "BiCGSTAB for a nonsymmetric K").
// The hand-written CG stays for SPD K: its work vectors are kept across
// solves (Eigen's solvers allocate theirs per solve).
#pragma once

#include "../inner_solver.hpp"
#include "sparse_product.hpp"

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <type_traits>
#include <vector>

namespace nrmicp::detail {

/// One level of a hierarchy below a finer one, as pyamg's MultilevelSolver.Level: P maps this
/// level to the next finer one, R = Pᵀ (formed once), A = R A_finer P its Galerkin operator.
template <typename StorageIndex>
struct Level {
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  RowMatrix P, R, A;
};

/// The levels below a level, owned elsewhere (by nrmicp::Newton): level[0] is the next coarser one.
/// Not const: the finest level's V-cycle frees and restores the operators A (MultigridKrylov, `borrow`).
template <typename StorageIndex>
struct Hierarchy {
  Level<StorageIndex>* level = nullptr;
  std::size_t levels = 0;
  Hierarchy below() const { return levels ? Hierarchy{level + 1, levels - 1} : *this; }
};

template <typename StorageIndex>
class MultigridKrylov;

/// One changed entry of a matrix on a fixed pattern: M(row, col) += delta.
template <typename StorageIndex>
struct Change {
  StorageIndex row, col;
  double delta;
};

/// The V-cycle as a preconditioner of Eigen's iterative solvers (their preconditioner concept:
/// the set-up is MultigridKrylov::setup's, so compute/analyzePattern/factorize do nothing).
template <typename StorageIndex>
struct VCyclePreconditioner {
  const MultigridKrylov<StorageIndex>* mg = nullptr;
  template <typename M> VCyclePreconditioner& analyzePattern(const M&) { return *this; }
  template <typename M> VCyclePreconditioner& factorize(const M&) { return *this; }
  template <typename M> VCyclePreconditioner& compute(const M&) { return *this; }
  template <typename Rhs> Eigen::VectorXd solve(const Rhs& r) const {
    Eigen::VectorXd e;
    if constexpr (std::is_same_v<Rhs, Eigen::VectorXd>) mg->precondition(r, e);
    else mg->precondition(Eigen::VectorXd(r), e);
    return e;
  }
  Eigen::ComputationInfo info() const { return Eigen::Success; }
};

template <typename StorageIndex>
class MultigridKrylov {
 public:
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  using Vector = Eigen::VectorXd;

  /// The Krylov method stops when ‖b − Kz‖ ≤ the absolute target the caller gives, or without one at rtol ‖b‖.
  /// The Newton loop asks for a tenth of its tol, so that the step on the right active set meets
  /// tol and no more (‖b − Kz‖ on the inactive rows is ‖w‖ there, what Res measures), and on the
  /// coarse levels for a fraction of the iterate's Res (a start needs no more). CG's recursive
  /// residual keeps falling below the rounding floor of the true one, so any target is reached;
  /// if the true residual cannot follow, the Newton loop ends with its active set settled.
  static constexpr double rtol = 1e-12;
  static constexpr int default_max_iterations = 500;

  /// The hierarchy must outlive this object. `symmetric`: the systems K given to setup are
  /// symmetric (their column storage is their row storage; CG), else a row-major copy of each is
  /// kept (BiCGSTAB). `borrow`: the hierarchy's operators A_l become this V-cycle's K_l instead of
  /// being copied (start_from_hierarchy), and are freed while it works (restore_hierarchy).
  MultigridKrylov(Hierarchy<StorageIndex> h, bool symmetric, bool borrow = false)
      : grid_(h.level), levels_(h.levels), symmetric_(symmetric), borrow_(borrow) {
    k_.resize(levels_ + 1);
    bicgstab_.preconditioner().mg = this;
  }
  MultigridKrylov(const MultigridKrylov&) = delete;  // the preconditioner points here
  MultigridKrylov& operator=(const MultigridKrylov&) = delete;

  /// Galerkin operators of K and the coarsest factorization. K must outlive this until the next
  /// setup. False if singular.
  ///
  /// K keeps one pattern across Newton steps (detail/active_set.hpp: only its values change),
  /// so the Galerkin operators P_lᵀ K_l P_l keep theirs: their patterns are formed on the first
  /// setup, later setups only recompute the values (detail/sparse_product.hpp). `changes`, when
  /// given, lists every entry of K that changed since the previous successful setup; if they are
  /// few (max_changes) the operators are updated by P_lᵀ ΔK_l P_l level by level instead
  /// (a Newton step changes the rows and columns of the points that changed sets: a few hundred
  /// of 10⁵–10⁶; add_galerkin_change).
  bool setup(const ColMatrix& K, const std::vector<Change<StorageIndex>>* changes = nullptr) {
    if (borrow_ && !lent_) free_hierarchy();
    fine_ = &K;
    const bool same_pattern = fine_pattern_ == K.nonZeros();
    if (!symmetric_) copy_rows(K, same_pattern);
    if (!(same_pattern && changes && valid_ && update_galerkin(*changes))) {
      for (std::size_t l = 0; l < levels_; ++l) {
        if (l == 0) galerkin(0, fine(), k_[1].K, same_pattern);
        else galerkin(l, k_[l].K, k_[l + 1].K, same_pattern);
      }
    }
    fine_pattern_ = K.nonZeros();
    valid_ = finish_setup(K);
    return valid_;
  }

  /// Takes the hierarchy's own operators (Level::A, the Galerkin ones of the level's A) as those
  /// of a K equal to A with `nnz` stored entries: the first setup then updates them by K − A, or
  /// recomputes them on their patterns, instead of forming the patterns (and K P) anew. Copied,
  /// or taken (`borrow`: the hierarchy then holds none until restore_hierarchy).
  void start_from_hierarchy(Eigen::Index nnz) {
    for (std::size_t l = 0; l < levels_; ++l) {
      if (borrow_) k_[l + 1].K.swap(grid_[l].A);
      else k_[l + 1].K = grid_[l].A;
    }
    lent_ = borrow_;
    fine_pattern_ = nnz;
    valid_ = true;
  }

  /// Whether the hierarchy's operators are freed while this V-cycle works (`borrow`).
  bool lent() const { return lent_; }

  /// The hierarchy's operators formed again, as the Galerkin ones of `A_values` (a column-major
  /// matrix on K's pattern holding A's values), on the patterns of this V-cycle's K_l, which stay
  /// as they are (the next setup updates them from the last K). The next setup frees them again.
  /// A_l and K_l have one pattern and the coarse levels need A_l only for nested iteration, before
  /// the finest level's solve: not held during it, for one pass of the Galerkin products a solve
  /// (docs/MEASUREMENTS.md, "The algebraic hierarchy on grids", Memory).
  template <typename M>
  void restore_hierarchy(const M& A_values) {
    if (!lent_) return;
    if (!symmetric_) copy_rows(A_values, fine_pattern_ == A_values.nonZeros());  // rows_: K's again at setup
    for (std::size_t l = 0; l < levels_; ++l) {
      grid_[l].A = k_[l + 1].K;   // its pattern
      if (l == 0) galerkin(0, symmetric_ ? rows(A_values) : rows(rows_), grid_[0].A, true);
      else galerkin(l, grid_[l - 1].A, grid_[l].A, true);
    }
    lent_ = false;
  }
  /// The most changed entries of K (of `nnz`) that setup applies as an update: each costs about
  /// as much as 5 entries of the full product (a search in C's row per term; docs/MEASUREMENTS.md,
  /// "`MultigridKrylov::max_changes` = nnz / 8").
  static std::size_t max_changes(Eigen::Index nnz) { return static_cast<std::size_t>(nnz / 8); }

  /// K z = b from the start z (the current Newton iterate: close), until ‖b − Kz‖ ≤ `target`
  /// (absolute), or ≤ rtol ‖b‖ when target is 0: CG for a symmetric K, else BiCGSTAB. Returns
  /// the number of iterations (max_iterations + 1 when not converged or broken down).
  int solve(const Vector& b, Vector& z, double target = 0) const {
    const double stop = target > 0 ? target : rtol * b.norm();
    return symmetric_ ? cg(b, z, stop) : krylov(b, z, stop);
  }

  /// e = one V-cycle applied to r (≈ K⁻¹ r).
  void precondition(const Vector& r, Vector& e) const { vcycle(0, r, e); }

  const char* name() const { return symmetric_ ? "cg" : "bicgstab"; }
  int max_iterations() const { return max_iterations_; }
  void set_max_iterations(int k) { max_iterations_ = k; }
  std::size_t levels() const { return levels_ + 1; }

 private:
  /// C = P_lᵀ `finer` P_l, the Galerkin operator of level l's finer one: only its values when
  /// `keep_pattern` and every term falls inside C's pattern, else C formed anew.
  template <typename M>
  void galerkin(std::size_t l, const M& finer, RowMatrix& C, bool keep_pattern) {
    const Level<StorageIndex>& g = grid_[l];
    if (keep_pattern && galerkin_values(g.R, finer, g.P, C, position_)) return;
    RowMatrix formed = product(g.R, product(finer, g.P));
    C.swap(formed);   // Eigen 3.4's SparseMatrix has no move assignment: = would copy
  }

  /// The hierarchy's operators freed (restored by restore_hierarchy; `borrow`).
  void free_hierarchy() {
    for (std::size_t l = 0; l < levels_; ++l) {
      RowMatrix none;
      grid_[l].A.swap(none);
    }
    lent_ = true;
  }

  /// 1 / diag of every level and the coarsest factorization, after the operators changed.
  bool finish_setup(const ColMatrix& K) {
    for (std::size_t l = 0; l < levels_; ++l) {
      k_[l].inv_diag = (l == 0 ? Vector(K.diagonal()) : Vector(k_[l].K.diagonal())).cwiseInverse();
      if (!k_[l].inv_diag.allFinite()) return false;
      if (!symmetric_) k_[l].reach = l == 0 ? reach_of(rows_) : reach_of(k_[l].K);
    }
    const ColMatrix coarsest = levels_ == 0 ? K : ColMatrix(k_.back().K);
    try {
      coarsest_.compute(coarsest, Inner::Auto, "the coarsest multigrid level");
    } catch (const std::runtime_error&) {
      return false;
    }
    if (!symmetric_) bicgstab_.compute(rows_);
    return true;
  }

  /// The Galerkin operators updated level by level for K's changed entries. False (some levels
  /// updated, the rest not: setup then recomputes them all) when there are too many changes or
  /// a term falls outside a level's pattern.
  bool update_galerkin(const std::vector<Change<StorageIndex>>& changes) {
    if (changes.size() > max_changes(fine_pattern_)) return false;
    const std::vector<Change<StorageIndex>>* in = &changes;
    for (std::size_t l = 0; l < levels_; ++l) {
      std::vector<Change<StorageIndex>>& out = level_changes_[l % 2];
      if (!add_galerkin_change(grid_[l].P, *in, k_[l + 1].K, out)) return false;
      in = &out;
    }
    return true;
  }

  /// C += Pᵀ ΔK P, ΔK given by its changed entries (`in`); `out` gets C's changed entries. The
  /// terms are added to C's values in place; a touched position's value before the update is kept
  /// in `out` and its change is the difference (no dense sum per position of C: docs/MEASUREMENTS.md,
  /// "The algebraic hierarchy on grids", Memory). False when a term falls outside C's pattern (C then
  /// partly updated).
  bool add_galerkin_change(const RowMatrix& P, const std::vector<Change<StorageIndex>>& in, RowMatrix& C,
                           std::vector<Change<StorageIndex>>& out) {
    const StorageIndex *po = P.outerIndexPtr(), *pi = P.innerIndexPtr(), *co = C.outerIndexPtr(),
                       *ci = C.innerIndexPtr();
    const double* pv = P.valuePtr();
    double* cv = C.valuePtr();
    listed_.resize(static_cast<std::size_t>(C.nonZeros()), false);  // all false between calls
    out.clear();                                                      // (row, position, value before)
    bool inside = true;
    for (const auto& change : in) {
      for (StorageIndex a = po[change.row]; a < po[change.row + 1] && inside; ++a)
        for (StorageIndex b = po[change.col]; b < po[change.col + 1]; ++b) {
          const StorageIndex* begin = ci + co[pi[a]];
          const StorageIndex* end = ci + co[pi[a] + 1];
          const StorageIndex* at = std::lower_bound(begin, end, pi[b]);
          if (at == end || *at != pi[b]) { inside = false; break; }
          const auto p = static_cast<std::size_t>(at - ci);
          if (!listed_[p]) { listed_[p] = true; out.push_back({pi[a], static_cast<StorageIndex>(p), cv[p]}); }
          cv[p] += pv[a] * change.delta * pv[b];
        }
      if (!inside) break;
    }
    for (auto& change : out) {   // col holds the position, delta the value before, until here
      const auto p = static_cast<std::size_t>(change.col);
      change.delta = cv[p] - change.delta;
      change.col = ci[p];
      listed_[p] = false;
    }
    return inside;
  }

  /// Preconditioned CG; ‖b − Kz‖ ≤ stop, the target as given (no bound by rtol ‖b‖: it cost
  /// iterations; docs/MEASUREMENTS.md, "The Krylov target taken as given").
  int cg(const Vector& b, Vector& z, double stop) const {
    const auto K = fine();
    Vector &r = cg_.r, &s = cg_.s, &p = cg_.p, &Kp = cg_.Kp;  // reused: no page faults per solve
    r.noalias() = K * z;
    r = b - r;
    if (r.norm() <= stop) return 0;
    s.resize(b.size()); p.resize(b.size()); Kp.resize(b.size());
    vcycle(0, r, s);
    p = s;
    double rs = r.dot(s);
    for (int k = 1; k <= max_iterations_; ++k) {
      Kp.noalias() = K * p;
      const double alpha = rs / p.dot(Kp);
      z += alpha * p;
      r -= alpha * Kp;
      if (r.norm() <= stop) return k;
      vcycle(0, r, s);
      const double rs_new = r.dot(s);
      p = s + (rs_new / rs) * p;
      rs = rs_new;
    }
    return max_iterations_ + 1;
  }

  /// Eigen's preconditioned BiCGSTAB (its residual is the unpreconditioned b − Kz, relative to
  /// ‖b‖, updated recursively as CG's is) until ‖b − Kz‖ ≤ stop. z is kept when the solve breaks
  /// down (a non-finite iterate). The convergence is Eigen's test on the recursive residual: the
  /// true one has a rounding floor (docs/MEASUREMENTS.md, "BiCGSTAB for a nonsymmetric K") that the Newton loop's
  /// target tol / 10 can lie below, where a check of the true residual would fail every step.
  int krylov(const Vector& b, Vector& z, double stop) const {
    const double bn = b.norm();
    if (bn == 0) { z.setZero(); return 0; }
    auto& s = bicgstab_;
    s.setMaxIterations(max_iterations_);
    s.setTolerance(stop / bn);
    Vector x = s.solveWithGuess(b, z);
    const int k = static_cast<int>(s.iterations());
    if (!x.allFinite()) return max_iterations_ + 1;
    z.swap(x);
    return s.info() == Eigen::Success ? k : max_iterations_ + 1;
  }

  /// M's compressed storage read as rows: M's own rows when row-major, Mᵀ's when column-major
  /// (= M for a symmetric M).
  template <typename M>
  static Eigen::Map<const RowMatrix> rows(const M& K) {
    return Eigen::Map<const RowMatrix>(K.rows(), K.cols(), K.nonZeros(), K.outerIndexPtr(), K.innerIndexPtr(),
                                       K.valuePtr());
  }
  /// The fine operator, row-major: K's own storage when symmetric, else its row copy.
  Eigen::Map<const RowMatrix> fine() const { return symmetric_ ? rows(*fine_) : rows(rows_); }

  /// rows_ = K in row-major storage; on K's previous pattern only the values are copied
  /// (through to_row_: K's storage position → rows_' storage position).
  template <typename M>
  void copy_rows(const M& K, bool same_pattern) {
    const StorageIndex* outer = K.outerIndexPtr();
    const StorageIndex* row = K.innerIndexPtr();
    if (!same_pattern || rows_.nonZeros() != K.nonZeros()) {
      rows_ = K;  // Eigen transposes the storage; rows come out sorted
      to_row_.resize(static_cast<std::size_t>(K.nonZeros()));
      std::vector<StorageIndex> next(rows_.outerIndexPtr(), rows_.outerIndexPtr() + K.rows());
      for (Eigen::Index j = 0; j < K.cols(); ++j)
        for (StorageIndex p = outer[j]; p < outer[j + 1]; ++p) to_row_[p] = next[row[p]]++;
      return;
    }
    const double* v = K.valuePtr();
    double* w = rows_.valuePtr();
    for (Eigen::Index p = 0; p < K.nonZeros(); ++p) w[to_row_[p]] = v[p];
  }

  /// One Gauss–Seidel sweep on M e = r, forward or backward; `after_row(i)` runs once e_i is new.
  struct NoHook {
    void operator()(Eigen::Index) const {}
  };
  template <typename M, typename AfterRow = NoHook>
  static void gauss_seidel(const M& A, const Vector& inv_diag, const Vector& r, Vector& e, bool forward,
                           AfterRow after_row = {}) {
    const Eigen::Index n = A.rows();
    const StorageIndex* outer = A.outerIndexPtr();
    const StorageIndex* col = A.innerIndexPtr();
    const double* v = A.valuePtr();
    for (Eigen::Index t = 0; t < n; ++t) {
      const Eigen::Index i = forward ? t : n - 1 - t;
      double sum = r[i];
      for (StorageIndex p = outer[i]; p < outer[i + 1]; ++p) sum -= v[p] * e[col[p]];
      e[i] += sum * inv_diag[i];
      after_row(i);
    }
  }

  /// The pre-smoothing of level l: the forward sweep on M e = r from e = 0 and the residual it
  /// leaves, res = r − M e = −(strict upper part of M) e, without a second read of M (docs/
  /// MEASUREMENTS.md, "Fused sweep"). A symmetric M: row j's entries left of the diagonal are column
  /// j's above it, so once e_j is known they scatter −m_ij e_j into res_i (i < j). Any M: row i's
  /// residual is final once e is known up to i + reach (M's largest column − row), so it is formed
  /// that many rows behind the sweep, while row i is still in cache (a grid's reach is a line or a
  /// plane of unknowns). Exact only for a plain sweep (inv_diag = 1 / diag(M): the lower part's
  /// residual it drops is zero then); a damped one needs the product again.
  template <typename M>
  void presmooth(const M& A, const Vector& inv_diag, Eigen::Index reach, const Vector& r, Vector& e, Vector& res) const {
    const Eigen::Index n = A.rows();
    const StorageIndex* outer = A.outerIndexPtr();
    const StorageIndex* col = A.innerIndexPtr();
    const double* v = A.valuePtr();
    e.setZero(n);
    res.resize(n);
    if (symmetric_) {
      gauss_seidel(A, inv_diag, r, e, true, [&](Eigen::Index j) {
        res[j] = 0.0;   // rows after j add to it
        for (StorageIndex p = outer[j]; p < outer[j + 1]; ++p)
          if (col[p] < j) res[col[p]] -= v[p] * e[j];
      });
      return;
    }
    auto upper_residual = [&](Eigen::Index i) {
      double s = 0.0;
      for (StorageIndex p = outer[i]; p < outer[i + 1]; ++p)
        if (col[p] > i) s -= v[p] * e[col[p]];
      res[i] = s;
    };
    gauss_seidel(A, inv_diag, r, e, true, [&](Eigen::Index j) {
      if (j >= reach) upper_residual(j - reach);
    });
    for (Eigen::Index i = std::max<Eigen::Index>(n - reach, 0); i < n; ++i) upper_residual(i);
  }

  /// The largest column − row of M's entries (0 for a lower-triangular M).
  template <typename M>
  static Eigen::Index reach_of(const M& A) {
    const StorageIndex* outer = A.outerIndexPtr();
    const StorageIndex* col = A.innerIndexPtr();
    Eigen::Index reach = 0;
    for (Eigen::Index i = 0; i < A.rows(); ++i)
      for (StorageIndex p = outer[i]; p < outer[i + 1]; ++p) reach = std::max<Eigen::Index>(reach, col[p] - i);
    return reach;
  }

  /// e ≈ K_l⁻¹ r: one V-cycle on level l.
  void vcycle(std::size_t l, const Vector& r, Vector& e) const {
    if (l == levels_) { coarsest_.solve(r, e); return; }
    KLevel& k = k_[l];
    auto smooth_and_correct = [&](const auto& A) {
      presmooth(A, k.inv_diag, k.reach, r, e, k.res);
      k.rc.noalias() = grid_[l].R * k.res;
      vcycle(l + 1, k.rc, k.ec);
      e.noalias() += grid_[l].P * k.ec;
      gauss_seidel(A, k.inv_diag, r, e, false);
    };
    if (l == 0) smooth_and_correct(fine());
    else smooth_and_correct(k_[l].K);
  }

  /// Level l of the reduced system: K_l = R K_{l−1} P (l ≥ 1; level 0 is the fine K), 1 / diag(K_l)
  /// (l < coarsest) and the V-cycle's vectors there.
  struct KLevel {
    RowMatrix K;
    Vector inv_diag, res, rc, ec;
    Eigen::Index reach = 0;   // nonsymmetric K_l: its largest column − row (the lagged residual's)
  };
  struct CGWork {
    Vector r, s, p, Kp;
  };
  mutable CGWork cg_;
  Level<StorageIndex>* grid_;             // the levels below: prolongations, restrictions, A_l
  std::size_t levels_;
  mutable std::vector<KLevel> k_;         // K_0 (= fine_), K_1, ...: the reduced system per level
  Eigen::Index fine_pattern_ = -1;        // nonzeros of the K the patterns were formed for
  bool valid_ = false;                    // the last setup succeeded (an update builds on it)
  std::vector<Change<StorageIndex>> level_changes_[2];   // scratch of update_galerkin
  std::vector<bool> listed_;              // scratch of add_galerkin_change: a position of C is in its list
  std::vector<StorageIndex> position_;    // scratch of product_values
  const ColMatrix* fine_ = nullptr;
  bool symmetric_;
  bool borrow_;                           // the hierarchy's A_l are freed while this V-cycle works
  bool lent_ = false;                     // ... and are now (restore_hierarchy forms them again)
  int max_iterations_ = default_max_iterations;
  RowMatrix rows_;                        // K in row-major storage (nonsymmetric K)
  std::vector<StorageIndex> to_row_;      // K's storage position → rows_'
  InnerSolver<StorageIndex> coarsest_;
  mutable Eigen::BiCGSTAB<RowMatrix, VCyclePreconditioner<StorageIndex>> bicgstab_;
};

}  // namespace nrmicp::detail
