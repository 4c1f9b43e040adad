// nrmicp — the nesting hierarchy of the Newton member on PETSc (hierarchy 'amg'): prolongations P_l and
// coarse operators A_{l+1} = P_lᵀ A_l P_l built from A by hypre BoomerAMG (PCHYPRE, read with
// PCGetInterpolations / PCGetCoarseOperators), for nrmicp::Newton<petsc::Matrix>:
//
//   const nrmicp::petsc::AmgHierarchy h = nrmicp::petsc::amg_hierarchy(A);
//   nrmicp::Newton<nrmicp::petsc::Matrix> newton(A, options, h.prolongations, h.coarse_operators);
//
// The rule (the serial amg set-up's fold, python/nrmicp/_hierarchy.py): one classical level first (hypre's
// Falgout coarsening, classical interpolation, strong threshold kStrongThreshold); where it holds more than kFoldDensity times A's nonzeros
// (7-point 3D grids) it is folded into the next (P_0 P_1, its operator not kept) and the levels below it
// use HMIS coarsening and direct interpolation with at most 4 weights a row (direct, as the serial fold's
// levels below: its coarse levels and finest steps; ext+i took a fifth step in 3D); elsewhere (2D grids, P1 and P2 elements) the levels below are classical too,
// with kStrongThreshold
// (docs/MEASUREMENTS.md, "The nesting hierarchy on PETSc"). PETSc options with the prefix
// nrmicp_hierarchy_ replace the rule: one set-up of the PC with them (-nrmicp_hierarchy_pc_hypre_boomeramg_...,
// or -nrmicp_hierarchy_pc_type gamg: any PC with PCGetInterpolations), hypre's defaults otherwise.
#pragma once

#include "engine.hpp"

#include <petscksp.h>

#include <cstring>
#include <string>
#include <utility>
#include <vector>

namespace nrmicp::petsc {

/// A nesting hierarchy, finest first: nrmicp::Newton's `prolongations` and `coarse_operators`.
struct AmgHierarchy {
  std::vector<Matrix> prolongations;
  std::vector<Matrix> coarse_operators;
  std::string reason;  ///< why no level was built ("" when the set-up ran): a cold start, as serially
};

/// PETSc options with this prefix build the hierarchy (the rule of amg_hierarchy gives way to them).
inline constexpr const char* kHierarchyPrefix = "nrmicp_hierarchy_";
/// BoomerAMG's strong threshold on the classical levels: with hypre's default, 0.25, P2's first level keeps more
/// coarse points than the serial set-up's and the nest takes more finest steps (docs/MEASUREMENTS.md, "The
/// strong threshold of the classical levels").
inline constexpr const char* kStrongThreshold = "0.1";
using detail::kFoldDensity;  // (the serial set-up's threshold too)

namespace hierarchy_detail {

using Option = std::pair<const char*, const char*>;

/// PETSc options `-prefix name value` in the database while this object lives, each only where the
/// user has not given it; removed after (nothing of ours stays behind).
class ScopedOptions {
 public:
  ScopedOptions(const std::string& prefix, const std::vector<Option>& values) {
    for (const auto& [name, value] : values) {
      const std::string key = "-" + prefix + name;
      PetscBool given = PETSC_FALSE;
      check(PetscOptionsHasName(nullptr, nullptr, key.c_str(), &given), "PetscOptionsHasName");
      if (!given) {
        check(PetscOptionsSetValue(nullptr, key.c_str(), value), "PetscOptionsSetValue");
        set_.push_back(key);
      }
    }
  }
  ScopedOptions(const ScopedOptions&) = delete;
  ScopedOptions& operator=(const ScopedOptions&) = delete;
  ~ScopedOptions() {
    for (const std::string& key : set_) PetscOptionsClearValue(nullptr, key.c_str());
  }

 private:
  std::vector<std::string> set_;
};

/// Whether the options database holds any option with `prefix` (the user's choice of hierarchy).
inline bool user_options(const std::string& prefix) {
  char* all = nullptr;
  check(PetscOptionsGetAll(nullptr, &all), "PetscOptionsGetAll");
  const bool found = all && std::strstr(all, ("-" + prefix).c_str());
  PetscFree(all);
  return found;
}

/// Takes over the Mats of a PETSc array (coarsest first) as Matrix objects, finest first.
inline std::vector<Matrix> finest_first(Mat* mats, PetscInt count) {
  std::vector<Matrix> out;
  for (PetscInt l = count - 1; l >= 0; --l) {
    out.emplace_back(mats[l]);
    MatDestroy(&mats[l]);
  }
  PetscFree(mats);
  return out;
}

/// One set-up of a PC on A with the options under `prefix` (BoomerAMG unless they choose another PC
/// type) and `ours` where the user gives none of them: its levels, finest first.
inline AmgHierarchy set_up(Mat A, const std::string& prefix, const std::vector<Option>& ours) {
  MPI_Comm comm;
  check(PetscObjectGetComm(reinterpret_cast<PetscObject>(A), &comm), "PetscObjectGetComm");
  PC pc;
  check(PCCreate(comm, &pc), "PCCreate");
  AmgHierarchy h;
  PetscErrorCode e = PCSetOptionsPrefix(pc, prefix.c_str());
  if (!e) e = PCSetOperators(pc, A, A);
  if (!e) e = PCSetType(pc, PCHYPRE);
  if (!e) e = PCHYPRESetType(pc, "boomeramg");
  if (!e) {
    const ScopedOptions scoped(prefix, ours);
    e = PCSetFromOptions(pc);
  }
  if (!e) e = PCSetUp(pc);
  PetscInt levels = 0;
  Mat* mats = nullptr;
  if (!e) e = PCGetInterpolations(pc, &levels, &mats);
  if (!e) h.prolongations = finest_first(mats, levels - 1);
  if (!e) e = PCGetCoarseOperators(pc, &levels, &mats);
  if (!e) h.coarse_operators = finest_first(mats, levels - 1);
  PCDestroy(&pc);
  check(e, "the hierarchy's set-up (PCSetUp, PCGetInterpolations)");
  return h;
}

/// P_0 P_1 in place of P_0 and P_1, the operator between them dropped.
inline void fold_first(AmgHierarchy& h) {
  Mat F;
  check(MatMatMult(h.prolongations[0].get(), h.prolongations[1].get(), MAT_INITIAL_MATRIX, PETSC_DEFAULT, &F),
        "MatMatMult");
  h.prolongations[1] = Matrix(F);
  MatDestroy(&F);
  h.prolongations.erase(h.prolongations.begin());
  h.coarse_operators.erase(h.coarse_operators.begin());
}

/// Why A cannot be coarsened (hypre's smoothers and interpolation divide by a_ii; it crashes on a zero one):
/// the first row whose diagonal entry is not positive (NaN included), or "". Collective.
inline std::string nonpositive_diagonal(Mat A) {
  MPI_Comm comm;
  check(PetscObjectGetComm(reinterpret_cast<PetscObject>(A), &comm), "PetscObjectGetComm");
  Vec d;
  check(MatCreateVecs(A, nullptr, &d), "MatCreateVecs");
  PetscInt lo = 0, n = 0, first = PETSC_MAX_INT;
  const PetscScalar* a = nullptr;
  PetscErrorCode e = MatGetDiagonal(A, d);
  if (!e) e = VecGetOwnershipRange(d, &lo, nullptr);
  if (!e) e = VecGetLocalSize(d, &n);
  if (!e) e = VecGetArrayRead(d, &a);
  for (PetscInt i = 0; !e && i < n && first == PETSC_MAX_INT; ++i)
    if (!(PetscRealPart(a[i]) > 0)) first = lo + i;
  if (a) VecRestoreArrayRead(d, &a);
  MPI_Allreduce(MPI_IN_PLACE, &first, 1, MPIU_INT, MPI_MIN, comm);  // (every process, whatever e)
  VecDestroy(&d);
  check(e, "MatGetDiagonal");
  if (first == PETSC_MAX_INT) return "";  // (the row only: the core may hold σA)
  return "A's diagonal is not positive at row " + std::to_string(first) + " (the amg set-up divides by it)";
}

}  // namespace hierarchy_detail

/// The nesting hierarchy of A by the rule above, or by the user's options under `prefix` when any are
/// given; none, with the reason, where A's diagonal is not positive. Collective on A's communicator; the levels hold their own references (no PC is kept).
inline AmgHierarchy amg_hierarchy(const Matrix& A, const std::string& prefix = kHierarchyPrefix) {
  using namespace hierarchy_detail;
  const std::string b = "pc_hypre_boomeramg_";
  if (std::string why = nonpositive_diagonal(A.get()); !why.empty()) return {{}, {}, std::move(why)};
  if (user_options(prefix)) return set_up(A.get(), prefix, {});
  // the first level alone (its coarse "solve" never runs: no Gaussian elimination of it)
  const std::string max_levels = b + "max_levels", coarse = b + "relax_type_coarse", strong = b + "strong_threshold";
  AmgHierarchy h = set_up(A.get(), prefix, {{max_levels.c_str(), "2"}, {coarse.c_str(), "symmetric-SOR/Jacobi"},
                                            {strong.c_str(), kStrongThreshold}});
  if (h.prolongations.empty()) return h;
  const bool dense = static_cast<double>(global_nonzeros(h.coarse_operators[0].get())) >
                     kFoldDensity * static_cast<double>(global_nonzeros(A.get()));
  const std::string coarsen = b + "coarsen_type", interp = b + "interp_type", p_max = b + "P_max";
  std::vector<Option> below = {{strong.c_str(), kStrongThreshold}};
  if (dense) below = {{coarsen.c_str(), "HMIS"}, {interp.c_str(), "direct"}, {p_max.c_str(), "4"}};
  AmgHierarchy rest = set_up(h.coarse_operators[0].get(), prefix, below);
  for (auto& P : rest.prolongations) h.prolongations.push_back(std::move(P));
  for (auto& C : rest.coarse_operators) h.coarse_operators.push_back(std::move(C));
  if (dense && h.prolongations.size() > 1) fold_first(h);
  return h;
}

}  // namespace nrmicp::petsc
