// nrmicp — the PETSc engine's Galerkin operators K_{l+1} = P_lᵀ K_l P_l of a Newton step's reduced
// system K (the serial engine's detail/galerkin.hpp, on PETSc Mats): PCMG's coarse operators, kept
// across Newton steps. K keeps A's pattern (its zeros stored), so the operators keep the
// patterns of A's: the first form starts, as the serial engine's, from copies of the hierarchy's
// operators (A's own Galerkin ones) updated by K − A (else MatPtAP forms them); later steps add
// P_lᵀ ΔK_l P_l level by level when K changed in few entries (GalerkinUpdate::max_changes of K's
// entries, counted over every process), else recompute them by MatPtAP (new Mats in place of the copies). The
// update: on one process detail::GalerkinUpdate, the serial engine's own, on the Mats' CSR arrays; on
// several, DistributedUpdate (the same terms, the rows of P and C they need exchanged between the
// processes that own them).
#pragma once

#include "../detail/galerkin.hpp"
#include "local_rows.hpp"

#include <petscksp.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace nrmicp::petsc {

/// C_l += P_lᵀ ΔK_l P_l level by level on several processes (detail::GalerkinUpdate's scheme, the
/// rows spread over processes). A change (i, j, δ) of a level's K, i a row this process owns, takes
/// row j of P from its owner; each term P(i, a) δ P(j, b) goes to the owner of C's row a, which adds
/// it in place and lists its changed entries: the next level's changes. Per level, two exchanges for
/// P's rows (request, reply), one for the terms, one reduction (whether every term fell inside C).
class DistributedUpdate {
 public:
  using Changes = std::vector<detail::Change<PetscInt>>;  // global numbers, rows this process owns

  /// C_1, ..., C_L updated for `changes` of the fine K; P[l], C[l]: P_l and C_{l+1}. False on every
  /// process alike when a term falls outside a level's pattern (some levels updated: recompute them
  /// all). Collective.
  bool apply(const Changes& changes, const std::vector<Mat>& P, const std::vector<Mat>& C) {
    const Changes* in = &changes;
    for (std::size_t l = 0; l < P.size(); ++l) {
      Changes& out = level_changes_[l % 2];
      if (!add_change(P[l], C[l], *in, out)) return false;
      in = &out;
    }
    return true;
  }

 private:
  struct Term {
    PetscInt row, col;
    double value;
  };
  struct Entry {
    PetscInt col;
    double value;
  };
  struct Touched {  // a position of C changed by this level's terms, and its value before them
    PetscInt row, col, position;
    double before;
  };

  /// C += Pᵀ ΔK P, ΔK given by `in`; `out` gets the changed entries of C's rows this process owns.
  bool add_change(Mat P, Mat C, const Changes& in, Changes& out) {
    MPI_Comm comm;
    PetscObjectGetComm(reinterpret_cast<PetscObject>(C), &comm);
    int inside = 1;
    {
      const LocalRows p(P, false);
      fetch_rows(comm, P, p, in);
      LocalRows c(C, true);  // (assembled again when it goes: PCMG's smoothers see the new values)
      const PetscInt* ranges;
      MatGetOwnershipRanges(C, &ranges);
      c_lo_ = c.row_begin();
      listed_.resize(std::max(listed_.size(), static_cast<std::size_t>(c.nonzeros())), 0);
      terms(comm, p, c, ranges, in, inside);
      out.clear();
      for (const Touched& t : touched_) {
        out.push_back({t.row, t.col, c.value(t.position) - t.before});
        listed_[static_cast<std::size_t>(t.position)] = 0;
      }
      touched_.clear();
    }
    MPI_Allreduce(MPI_IN_PLACE, &inside, 1, MPI_INT, MPI_LAND, comm);
    return inside != 0;
  }

  /// The rows j of P that `in` needs and other processes own, from them (remote_, sorted by row).
  void fetch_rows(MPI_Comm comm, Mat P, const LocalRows& p, const Changes& in) {
    int processes, rank;
    MPI_Comm_size(comm, &processes);
    MPI_Comm_rank(comm, &rank);
    const PetscInt* ranges;
    MatGetOwnershipRanges(P, &ranges);
    std::vector<std::vector<PetscInt>> wanted(static_cast<std::size_t>(processes));
    for (const auto& change : in) {
      const int r = owner_of(ranges, processes, change.col);
      if (r != rank) wanted[static_cast<std::size_t>(r)].push_back(change.col);
    }
    for (auto& w : wanted) {
      std::sort(w.begin(), w.end());
      w.erase(std::unique(w.begin(), w.end()), w.end());
    }
    const Received<PetscInt> asked = all_to_all(comm, wanted);
    std::vector<std::vector<Term>> reply(static_cast<std::size_t>(processes));
    for (std::size_t s = 0; s < reply.size(); ++s)
      for (std::size_t k = asked.from[s]; k < asked.from[s + 1]; ++k) {
        const PetscInt j = asked.data[k];
        p.for_row(j - ranges[rank], [&](PetscInt b, double v) { reply[s].push_back({j, b, v}); });
      }
    remote_ = all_to_all(comm, reply).data;  // by source, each source's rows in the order asked: sorted
    p_lo_ = ranges[rank];
    p_hi_ = ranges[rank + 1];
  }

  /// Row g of P (this process's or fetched) into `row`.
  void row_of(const LocalRows& p, PetscInt g, std::vector<Entry>& row) const {
    row.clear();
    if (g >= p_lo_ && g < p_hi_) return p.for_row(g - p_lo_, [&](PetscInt b, double v) { row.push_back({b, v}); });
    const auto by_row = [](const Term& t, PetscInt r) { return t.row < r; };
    for (auto t = std::lower_bound(remote_.begin(), remote_.end(), g, by_row); t != remote_.end() && t->row == g; ++t)
      row.push_back({t->col, t->value});
  }

  /// Every term of `in`, added to C's rows here or sent to their owners (which add them); `inside`
  /// cleared when one falls outside C's pattern.
  void terms(MPI_Comm comm, const LocalRows& p, LocalRows& c, const PetscInt* ranges, const Changes& in, int& inside) {
    int processes, rank;
    MPI_Comm_size(comm, &processes);
    MPI_Comm_rank(comm, &rank);
    std::vector<std::vector<Term>> send(static_cast<std::size_t>(processes));
    const PetscInt c_hi = ranges[rank + 1];
    PetscInt row = -1;
    for (const auto& change : in) {
      if (change.row != row) row_of(p, row = change.row, row_i_);  // (in comes row by row)
      row_of(p, change.col, row_j_);
      for (const Entry& a : row_i_)
        for (const Entry& b : row_j_) {
          const Term t{a.col, b.col, a.value * change.delta * b.value};
          if (t.row >= c_lo_ && t.row < c_hi) add(c, t, inside);
          else send[static_cast<std::size_t>(owner_of(ranges, processes, t.row))].push_back(t);
        }
    }
    for (const Term& t : all_to_all(comm, send).data) add(c, t, inside);
  }

  /// C(t.row, t.col) += t.value, the position listed at its first change.
  void add(LocalRows& c, const Term& t, int& inside) {
    const PetscInt at = c.find(t.row - c_lo_, t.col);
    if (at < 0) { inside = 0; return; }
    auto& listed = listed_[static_cast<std::size_t>(at)];
    if (!listed) { listed = 1; touched_.push_back({t.row, t.col, at, c.value(at)}); }
    c.value(at) += t.value;
  }

  Changes level_changes_[2];     // scratch of apply
  std::vector<Term> remote_;     // rows of P fetched from other processes, as (row, column, value)
  PetscInt p_lo_ = 0, p_hi_ = 0, c_lo_ = 0;  // this process's rows of P and of C
  std::vector<Entry> row_i_, row_j_;
  std::vector<char> listed_;     // a position of C is in touched_ (all 0 between calls)
  std::vector<Touched> touched_;
};

/// K_1, ..., K_L of a fine K on the prolongations P_0, ..., P_{L-1} (finest first), as PETSc Mats.
class GalerkinOperators {
 public:
  using Changes = std::vector<detail::Change<PetscInt>>;

  /// `P`: the prolongations; `A`, `coarse` (optional): a fine A with the pattern of the fine K's to
  /// come and its Galerkin operators (the hierarchy's), the first form's start (all alive while this
  /// object is). Collective.
  explicit GalerkinOperators(std::vector<Mat> P, Mat A = nullptr, std::vector<Mat> coarse = {})
      : P_(std::move(P)), A_(A), coarse_(std::move(coarse)) {
    if (!A_ || coarse_.size() != P_.size()) coarse_.clear();
    if (!coarse_.empty()) nnz_ = global_nonzeros(A_);
  }
  GalerkinOperators(const GalerkinOperators&) = delete;
  GalerkinOperators& operator=(const GalerkinOperators&) = delete;
  ~GalerkinOperators() { destroy(); }

  /// K_{l+1}, l = 0, ..., levels − 1 (null before the first form).
  Mat K(std::size_t l) const { return C_.empty() ? nullptr : C_[l]; }
  std::size_t levels() const { return P_.size(); }
  /// Whether the last form updated the operators by K's change (neither formed nor recomputed them).
  bool updated() const { return updated_; }
  /// The most changed entries (every process's) the next form takes as an update: half of A's entries
  /// the first time (first_changes), GalerkinUpdate::max_changes of K's after; a caller records one more
  /// at most (form's `changes`).
  std::size_t most_changes() const {
    if (C_.empty()) return coarse_.empty() ? 0 : first_changes(nnz_);
    return detail::GalerkinUpdate<PetscInt>::max_changes(nnz_);
  }

  /// The operators of `fine` (assembled, one pattern throughout): the first time the hierarchy's
  /// operators (copies) updated by `changes` (fine − A) when there are at most most_changes(), else formed
  /// by MatPtAP; later updated by `changes` (fine's changed entries since the last form, global numbers,
  /// rows of this process) when they are at most most_changes() over every process, else recomputed by
  /// MatPtAP (values only, MAT_REUSE_MATRIX, once they are its products; new Mats when they were the
  /// copies). Returns whether the Mats are new (K(l) must be handed on again). `changes` null: not
  /// recorded (more than most_changes()). Collective.
  bool form(Mat fine, const Changes* changes) {
    const std::size_t most = most_changes();
    updated_ = false;
    if (C_.empty()) {
      updated_ = start(changes, most);
      if (updated_) return true;
      destroy();
      C_.resize(P_.size(), nullptr);
      for (std::size_t l = 0; l < P_.size(); ++l)
        check(MatPtAP(l ? C_[l - 1] : fine, P_[l], MAT_INITIAL_MATRIX, 2.0, &C_[l]), "MatPtAP");
      product_ = true;
      updatable_ = sorted(fine);
      nnz_ = global_nonzeros(fine);
      return true;
    }
    updated_ = updatable_ && update(fine, changes, most);
    if (updated_) return false;
    const bool fresh = !product_;  // the hierarchy's copies give way to new Mats: PCMG must take them
    recompute(fine);
    return fresh;
  }

 private:
  /// The first form from the hierarchy's operators (copies) updated by fine − A; false when there are
  /// none, too many changes or a term outside their patterns.
  bool start(const Changes* changes, std::size_t most) {
    if (coarse_.empty()) return false;
    C_.resize(P_.size(), nullptr);
    for (std::size_t l = 0; l < P_.size(); ++l) check(MatDuplicate(coarse_[l], MAT_COPY_VALUES, &C_[l]), "MatDuplicate");
    updatable_ = sorted(A_);
    return updatable_ && update(A_, changes, most);
  }
  /// The values recomputed on the patterns (MatPtAP, MAT_REUSE_MATRIX; formed first when the
  /// operators are the hierarchy's copies).
  void recompute(Mat fine) {
    const MatReuse reuse = product_ ? MAT_REUSE_MATRIX : MAT_INITIAL_MATRIX;
    if (!product_) destroy();
    C_.resize(P_.size(), nullptr);
    for (std::size_t l = 0; l < P_.size(); ++l)
      check(MatPtAP(l ? C_[l - 1] : fine, P_[l], reuse, 2.0, &C_[l]), "MatPtAP");
    product_ = true;
  }
  void destroy() {
    for (Mat& C : C_) MatDestroy(&C);
    C_.clear();
  }
  /// Every Mat's rows sorted (MatPtAP's are; the updates search them); every process alike.
  bool sorted(Mat fine) const {
    bool all = LocalRows(fine, false).sorted();
    for (std::size_t l = 0; l < P_.size(); ++l) {
      all = LocalRows(P_[l], false).sorted() && all;
      all = LocalRows(C_[l], false).sorted() && all;
    }
    return all;
  }
  static MPI_Comm comm_of(Mat M) {
    MPI_Comm c;
    PetscObjectGetComm(reinterpret_cast<PetscObject>(M), &c);
    return c;
  }
  /// The update by `changes`; false (every process alike) when they are not recorded or more than
  /// `most`, or a term falls outside a level's pattern (then recompute them all).
  bool update(Mat fine, const Changes* changes, std::size_t most) {
    std::uint64_t count = changes ? changes->size() : most + 1;
    MPI_Allreduce(MPI_IN_PLACE, &count, 1, MPI_UINT64_T, MPI_SUM, comm_of(fine));
    if (count > most) return false;
    int processes = 1;
    MPI_Comm_size(comm_of(fine), &processes);
    if (processes > 1) return distributed_.apply(*changes, P_, C_);
    std::vector<std::unique_ptr<LocalRows>> Ps, Cs;  // open while the update runs
    for (std::size_t l = 0; l < P_.size(); ++l) {
      Ps.push_back(std::make_unique<LocalRows>(P_[l], false));
      Cs.push_back(std::make_unique<LocalRows>(C_[l], true));
    }
    return update_.add(*changes, P_.size(), [&](std::size_t l) { return Ps[l]->diagonal_block(); },
                       [&](std::size_t l) { return Cs[l]->diagonal_block(); });
  }

  /// The most changes the first form takes as an update of the hierarchy's operators: half of K's
  /// entries (its alternative is MatPtAP's symbolic and numeric product, not a numeric one: a change
  /// cost 1.6–1.9 entries of it; docs/MEASUREMENTS.md, "The PETSc engine on two processes").
  static std::size_t first_changes(Eigen::Index nnz) { return static_cast<std::size_t>(nnz / 2); }

  std::vector<Mat> P_;
  Mat A_;                         // the hierarchy's level and its operators (the first form's start)
  std::vector<Mat> coarse_;
  std::vector<Mat> C_;
  bool product_ = false;          // C_ came from MatPtAP (MAT_REUSE_MATRIX applies)
  bool updatable_ = false;        // sorted rows: form may update
  bool updated_ = false;          // the last form updated
  Eigen::Index nnz_ = 0;          // the fine K's stored entries, every process's
  detail::GalerkinUpdate<PetscInt> update_;
  DistributedUpdate distributed_;
};

}  // namespace nrmicp::petsc
