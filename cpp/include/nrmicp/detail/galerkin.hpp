// nrmicp — the Galerkin operators K_{l+1} = P_lᵀ K_l P_l of the Newton step's reduced system K on a
// hierarchy's prolongations (the V-cycle's coarse levels: detail/vcycle.hpp, detail/multigrid.hpp).
//
// K keeps one pattern across Newton steps (detail/active_set.hpp: only its values change), so the
// Galerkin operators keep theirs: their patterns are formed once, later set-ups only recompute the
// values (detail/sparse_product.hpp) or, when K changed in few entries, add P_lᵀ ΔK_l P_l level by
// level (a Newton step changes the rows and columns of the points that changed sets: a few hundred
// of 10⁵–10⁶).
#pragma once

#include "sparse_product.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <cstddef>
#include <vector>

namespace nrmicp::detail {

/// A nesting hierarchy's first coarse operator with more than this many times A's nonzeros is folded
/// into the next level (P_0 P_1): both set-ups ask it, the serial (nrmicp._hierarchy, through
/// _core.newton_tuning) and the PETSc engine's (petsc/hierarchy.hpp). 7-point 3D grids give 1.26–1.34,
/// 2D grids 0.9, P1 0.8, P2 0.64 (docs/MEASUREMENTS.md, "The fold of a denser first coarse level").
inline constexpr double kFoldDensity = 1.2;

/// One level of a hierarchy below a finer one, as pyamg's MultilevelSolver.Level, in either engine's
/// matrices: P maps this level to the next finer one, R = Pᵀ (formed once), A = R A_finer P its Galerkin operator.
template <typename Matrix>
struct HierarchyLevel {
  Matrix P, R, A;
};

/// The levels below a level, owned elsewhere (by nrmicp::Newton): level[0] is the next coarser one.
/// Not const: the finest level's V-cycle frees and restores the operators A (GalerkinOperators, `borrow`).
template <typename LevelType>
struct LevelsBelow {
  LevelType* level = nullptr;
  std::size_t levels = 0;
  LevelsBelow below() const { return levels ? LevelsBelow{level + 1, levels - 1} : *this; }
};

/// The serial engine's: Eigen's row-major matrices.
template <typename StorageIndex>
using Level = HierarchyLevel<Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>>;
template <typename StorageIndex>
using Hierarchy = LevelsBelow<Level<StorageIndex>>;

/// One changed entry of a matrix on a fixed pattern: M(row, col) += delta.
template <typename StorageIndex>
struct Change {
  StorageIndex row, col;
  double delta;
};

/// M's compressed storage read as rows: M's own rows when row-major, Mᵀ's when column-major
/// (= M for a symmetric M).
template <typename M>
Eigen::Map<const Eigen::SparseMatrix<double, Eigen::RowMajor, typename M::StorageIndex>> as_rows(const M& K) {
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, typename M::StorageIndex>;
  return Eigen::Map<const RowMatrix>(K.rows(), K.cols(), K.nonZeros(), K.outerIndexPtr(), K.innerIndexPtr(),
                                     K.valuePtr());
}

/// The Galerkin operators updated by a fine K's changed entries: K_{l+1} += P_lᵀ ΔK_l P_l level by
/// level, each level's changed entries the next one's ΔK. Written once for both engines: a level's
/// P and K_{l+1} are row-major compressed views (Eigen matrices, or Maps over a PETSc SeqAIJ Mat's
/// arrays), given by the callables of apply.
template <typename StorageIndex>
class GalerkinUpdate {
 public:
  using Changes = std::vector<Change<StorageIndex>>;

  /// The most changed entries of K (of `nnz`) that apply takes as an update: each costs about
  /// as much as 5 entries of the full product (a search in C's row per term; docs/MEASUREMENTS.md,
  /// "`GalerkinOperators::max_changes` = nnz / 8").
  static std::size_t max_changes(Eigen::Index nnz) { return static_cast<std::size_t>(nnz / 8); }

  /// K_1, ..., K_levels updated for `changes` of a fine K with `nnz` stored entries; `P(l)` gives
  /// P_l, `C(l)` K_{l+1} (writable values). False (some levels updated, the rest not: recompute
  /// them all) when there are too many changes or a term falls outside a level's pattern.
  template <typename PAt, typename CAt>
  bool apply(const Changes& changes, Eigen::Index nnz, std::size_t levels, PAt&& P, CAt&& C) {
    return changes.size() <= max_changes(nnz) && add(changes, levels, P, C);
  }
  /// The same whatever the number of changes (the caller has decided they are few enough).
  template <typename PAt, typename CAt>
  bool add(const Changes& changes, std::size_t levels, PAt&& P, CAt&& C) {
    const Changes* in = &changes;
    for (std::size_t l = 0; l < levels; ++l) {
      Changes& out = level_changes_[l % 2];
      auto&& c = C(l);
      if (!add_change(P(l), *in, c, out)) return false;
      in = &out;
    }
    return true;
  }

 private:
  /// C += Pᵀ ΔK P, ΔK given by its changed entries (`in`); `out` gets C's changed entries. The
  /// terms are added to C's values in place; a touched position's value before the update is kept
  /// in `out` and its change is the difference (no dense sum per position of C: docs/MEASUREMENTS.md,
  /// "The algebraic hierarchy on grids", Memory). False when a term falls outside C's pattern (C then
  /// partly updated).
  template <typename PMatrix, typename CMatrix>
  bool add_change(const PMatrix& P, const Changes& in, CMatrix& C, Changes& out) {
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

  Changes level_changes_[2];              // scratch of apply
  std::vector<bool> listed_;              // scratch of add_change: a position of C is in its list
};

/// K_1, ..., K_L of a fine K (given row-major) on the hierarchy's P_l, R_l.
template <typename StorageIndex>
class GalerkinOperators {
 public:
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  using Changes = std::vector<Change<StorageIndex>>;

  /// The hierarchy must outlive this object. `borrow`: the hierarchy's operators A_l become K_l
  /// instead of being copied (start_from_hierarchy), and are freed while the V-cycle works (restore).
  GalerkinOperators(Hierarchy<StorageIndex> h, bool borrow) : grid_(h.level), levels_(h.levels), borrow_(borrow) {
    K_.resize(levels_);
  }

  /// GalerkinUpdate::max_changes.
  static std::size_t max_changes(Eigen::Index nnz) { return GalerkinUpdate<StorageIndex>::max_changes(nnz); }

  std::size_t levels() const { return levels_; }
  /// P_l, R_l of coarse level l + 1 (l = 0: the one below the fine level).
  const Level<StorageIndex>& level(std::size_t l) const { return grid_[l]; }
  /// K_l, l = 1, ..., levels().
  const RowMatrix& K(std::size_t l) const { return K_[l - 1]; }
  /// Whether a fine K with `nnz` stored entries has the pattern the operators were formed for.
  bool same_pattern(Eigen::Index nnz) const { return fine_pattern_ == nnz; }
  /// Whether the hierarchy's operators are freed while the V-cycle works (`borrow`).
  bool lent() const { return lent_; }

  /// The hierarchy's operators freed before a set-up (`borrow`; restore forms them again).
  void lend() {
    if (!borrow_ || lent_) return;
    for (std::size_t l = 0; l < levels_; ++l) {
      RowMatrix none;
      grid_[l].A.swap(none);
    }
    lent_ = true;
  }

  /// The operators of `fine` (row-major, `nnz` entries): updated by `changes` (K's changed entries
  /// since the last form that a V-cycle was built on; null: none known) when they are few
  /// (max_changes), else recomputed, on their patterns when K's is the same.
  template <typename Fine>
  void form(const Fine& fine, Eigen::Index nnz, const Changes* changes) {
    const bool same = same_pattern(nnz);
    if (!(same && changes && update(*changes))) {
      for (std::size_t l = 0; l < levels_; ++l) {
        if (l == 0) galerkin(0, fine, K_[0], same);
        else galerkin(l, K_[l - 1], K_[l], same);
      }
    }
    fine_pattern_ = nnz;
  }

  /// Takes the hierarchy's own operators (Level::A, the Galerkin ones of the level's A) as those
  /// of a K equal to A with `nnz` stored entries: the first form then updates them by K − A, or
  /// recomputes them on their patterns, instead of forming the patterns (and K P) anew. Copied,
  /// or taken (`borrow`: the hierarchy then holds none until restore).
  void start_from_hierarchy(Eigen::Index nnz) {
    for (std::size_t l = 0; l < levels_; ++l) {
      if (borrow_) K_[l].swap(grid_[l].A);
      else K_[l] = grid_[l].A;
    }
    lent_ = borrow_;
    fine_pattern_ = nnz;
  }

  /// The hierarchy's operators formed again, as the Galerkin ones of `A_rows` (A's values on K's
  /// pattern, row-major), on the patterns of K_l, which stay as they are.
  template <typename Fine>
  void restore(const Fine& A_rows) {
    for (std::size_t l = 0; l < levels_; ++l) {
      grid_[l].A = K_[l];   // its pattern
      if (l == 0) galerkin(0, A_rows, grid_[0].A, true);
      else galerkin(l, grid_[l - 1].A, grid_[l].A, true);
    }
    lent_ = false;
  }

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

  /// The operators updated level by level for K's changed entries (GalerkinUpdate::apply).
  bool update(const Changes& changes) {
    return update_.apply(changes, fine_pattern_, levels_, [this](std::size_t l) -> const RowMatrix& { return grid_[l].P; },
                         [this](std::size_t l) -> RowMatrix& { return K_[l]; });
  }

  Level<StorageIndex>* grid_;             // the levels below: prolongations, restrictions, A_l
  std::size_t levels_;
  std::vector<RowMatrix> K_;              // K_1, ..., K_L
  Eigen::Index fine_pattern_ = -1;        // nonzeros of the K the patterns were formed for
  bool borrow_;                           // the hierarchy's A_l are freed while the V-cycle works
  bool lent_ = false;                     // ... and are now (restore forms them again)
  GalerkinUpdate<StorageIndex> update_;   // the update by K's changed entries
  std::vector<StorageIndex> position_;    // scratch of product_values
};

}  // namespace nrmicp::detail
