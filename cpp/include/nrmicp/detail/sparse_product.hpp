// nrmicp — the sparse product C = L R of row-major matrices, split into a symbolic pass (C's
// pattern) and a numeric pass on a given pattern.
//
// Why not Eigen's product: the Galerkin operators of the Newton member's reduced system K are
// recomputed every Newton step, and K keeps one pattern (detail/active_set.hpp), so their
// patterns are fixed and only the values change; Eigen has no values-only product, and its
// product sorts each result by two storage-order conversions. Two passes (Gustavson's row-by-row
// method) make the per-step product a values-only one (docs/MEASUREMENTS.md, "The two-pass sparse
// product").
#pragma once

#include <Eigen/SparseCore>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <vector>

namespace nrmicp::detail {

/// The pattern of C = L R (row-major, compressed, sorted rows, values zero). L: any row-major
/// compressed sparse type (a matrix or a Map), R: a row-major compressed matrix.
template <typename Lhs, typename RowMatrix>
RowMatrix product_pattern(const Lhs& L, const RowMatrix& R) {
  static_assert(Lhs::IsRowMajor && RowMatrix::IsRowMajor, "product_pattern reads rows");
  using StorageIndex = typename RowMatrix::StorageIndex;
  const Eigen::Index rows = L.rows(), cols = R.cols();
  const StorageIndex *lo = L.outerIndexPtr(), *li = L.innerIndexPtr(), *ro = R.outerIndexPtr(),
                     *ri = R.innerIndexPtr();
  std::vector<StorageIndex> outer(static_cast<std::size_t>(rows) + 1, 0), inner;
  std::vector<Eigen::Index> last(static_cast<std::size_t>(cols), -1);  // the last row that used column j
  inner.reserve(static_cast<std::size_t>(L.nonZeros()));
  for (Eigen::Index i = 0; i < rows; ++i) {
    const std::size_t begin = inner.size();
    for (StorageIndex a = lo[i]; a < lo[i + 1]; ++a)
      for (StorageIndex b = ro[li[a]]; b < ro[li[a] + 1]; ++b)
        if (last[ri[b]] != i) { last[ri[b]] = i; inner.push_back(ri[b]); }
    std::sort(inner.begin() + begin, inner.end());
    if (inner.size() > static_cast<std::size_t>(std::numeric_limits<StorageIndex>::max()))
      throw std::overflow_error("sparse product: the result has more nonzeros than the index type holds");
    outer[i + 1] = static_cast<StorageIndex>(inner.size());
  }
  RowMatrix C(rows, cols);
  C.resizeNonZeros(static_cast<Eigen::Index>(inner.size()));
  std::copy(outer.begin(), outer.end(), C.outerIndexPtr());
  std::copy(inner.begin(), inner.end(), C.innerIndexPtr());
  std::fill(C.valuePtr(), C.valuePtr() + inner.size(), 0.0);
  return C;
}

/// C = L R on C's existing pattern: only the values are computed. `position` is scratch space
/// (a column → position map). False, with C's values unspecified, when a product term falls
/// outside C's pattern (then form the pattern again).
template <typename Lhs, typename RowMatrix>
bool product_values(const Lhs& L, const RowMatrix& R, RowMatrix& C,
                    std::vector<typename RowMatrix::StorageIndex>& position) {
  static_assert(Lhs::IsRowMajor && RowMatrix::IsRowMajor, "product_values reads rows");
  using StorageIndex = typename RowMatrix::StorageIndex;
  if (C.rows() != L.rows() || C.cols() != R.cols() || !C.isCompressed()) return false;
  position.assign(static_cast<std::size_t>(C.cols()), -1);
  const StorageIndex *lo = L.outerIndexPtr(), *li = L.innerIndexPtr(), *ro = R.outerIndexPtr(),
                     *ri = R.innerIndexPtr(), *co = C.outerIndexPtr(), *ci = C.innerIndexPtr();
  const double *lv = L.valuePtr(), *rv = R.valuePtr();
  double* cv = C.valuePtr();
  for (Eigen::Index i = 0; i < L.rows(); ++i) {
    for (StorageIndex p = co[i]; p < co[i + 1]; ++p) { position[ci[p]] = p; cv[p] = 0.0; }
    for (StorageIndex a = lo[i]; a < lo[i + 1]; ++a)
      for (StorageIndex b = ro[li[a]]; b < ro[li[a] + 1]; ++b) {
        const StorageIndex p = position[ri[b]];
        if (p < 0) return false;
        cv[p] += lv[a] * rv[b];
      }
    for (StorageIndex p = co[i]; p < co[i + 1]; ++p) position[ci[p]] = -1;
  }
  return true;
}

/// C = R K P on C's existing pattern (R = Pᵀ, all row-major), without forming K P: row i of C
/// sums r_ij (row j of K) P, term by term. False, with C's values unspecified, when a term falls
/// outside C's pattern. Keeping K P for a values-only two-product pass cost as much memory as K
/// (1e6 × 9-16 nonzeros on a 2D grid) for no gain in time (the flops are about equal).
template <typename Kmat, typename RowMatrix>
bool galerkin_values(const RowMatrix& R, const Kmat& K, const RowMatrix& P, RowMatrix& C,
                     std::vector<typename RowMatrix::StorageIndex>& position) {
  static_assert(Kmat::IsRowMajor && RowMatrix::IsRowMajor, "galerkin_values reads rows");
  using StorageIndex = typename RowMatrix::StorageIndex;
  if (C.rows() != R.rows() || C.cols() != P.cols() || !C.isCompressed()) return false;
  position.assign(static_cast<std::size_t>(C.cols()), -1);
  const StorageIndex *ro = R.outerIndexPtr(), *ri = R.innerIndexPtr(), *ko = K.outerIndexPtr(),
                     *ki = K.innerIndexPtr(), *po = P.outerIndexPtr(), *pi = P.innerIndexPtr(),
                     *co = C.outerIndexPtr(), *ci = C.innerIndexPtr();
  const double *rv = R.valuePtr(), *kv = K.valuePtr(), *pv = P.valuePtr();
  double* cv = C.valuePtr();
  for (Eigen::Index i = 0; i < C.rows(); ++i) {
    for (StorageIndex p = co[i]; p < co[i + 1]; ++p) { position[ci[p]] = p; cv[p] = 0.0; }
    for (StorageIndex a = ro[i]; a < ro[i + 1]; ++a)
      for (StorageIndex b = ko[ri[a]]; b < ko[ri[a] + 1]; ++b) {
        const double rk = rv[a] * kv[b];
        for (StorageIndex c = po[ki[b]]; c < po[ki[b] + 1]; ++c) {
          const StorageIndex p = position[pi[c]];
          if (p < 0) return false;
          cv[p] += rk * pv[c];
        }
      }
    for (StorageIndex p = co[i]; p < co[i + 1]; ++p) position[ci[p]] = -1;
  }
  return true;
}

/// C = L R (pattern and values); a column-major L is copied to rows first.
template <typename Lhs, typename RowMatrix>
RowMatrix product(const Lhs& L, const RowMatrix& R) {
  if constexpr (!Lhs::IsRowMajor) {
    return product(RowMatrix(L), R);
  } else {
    RowMatrix C = product_pattern(L, R);
    std::vector<typename RowMatrix::StorageIndex> position;
    product_values(L, R, C, position);
    return C;
  }
}

}  // namespace nrmicp::detail
