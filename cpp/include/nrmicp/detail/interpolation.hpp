// nrmicp — the algebraic hierarchy's interpolation sweeps (python/nrmicp/_hierarchy.py,
// _relax_interpolation): Jacobi sweeps on the F rows of a prolongation P towards B-harmonic
// (ideal) interpolation, each row truncated as it is formed. One pass over B and P per sweep,
// where scipy's product, sums, scaling and a separate truncation pass wrote four intermediates
// (docs/MEASUREMENTS.md, "The amg set-up's interpolation sweeps").
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <utility>
#include <vector>

namespace nrmicp::detail {

/// A CSR matrix as its three arrays (indptr starts at 0).
template <typename I>
struct CsrArrays {
  std::vector<I> indptr{0};
  std::vector<I> indices;
  std::vector<double> data;
};

/// Appends the row (column, value) to `out`: entries below `truncate` × its largest magnitude
/// dropped, the rest scaled to the row's former sum, sorted by column; no zeros (a row summing
/// to 0 scales to zeros, and a canonical P has none).
template <typename I>
void append_truncated(std::vector<std::pair<I, double>>& row, double truncate, CsrArrays<I>& out) {
  double largest = 0, sum = 0, kept = 0;
  for (const auto& e : row) {
    largest = std::max(largest, std::abs(e.second));
    sum += e.second;
  }
  row.erase(std::remove_if(row.begin(), row.end(), [&](const auto& e) { return std::abs(e.second) < truncate * largest; }),
            row.end());
  for (const auto& e : row) kept += e.second;
  const double scale = kept != 0 ? sum / kept : 1.0;
  std::sort(row.begin(), row.end());
  for (const auto& [k, v] : row)
    if (v * scale != 0) {
      out.indices.push_back(k);
      out.data.push_back(v * scale);
    }
  out.indptr.push_back(static_cast<I>(out.indices.size()));
}

/// `sweeps` Jacobi sweeps P_F ← −D_F⁻¹((B_FF − D_FF) P_F + B_FC) on the F rows of P (n × n_c, CSR),
/// its C rows kept (the identity in the coarse numbering, C points in order); each new row's
/// entries below `truncate` × its largest magnitude dropped and the rest scaled to the row's sum.
/// B: row-major n × n with a positive diagonal (the caller checks); `is_c`: n flags. When no F
/// point couples to another F point one sweep is the fixed point, so at most one is done.
/// Returns P canonical: sorted column indices, no explicit zeros.
template <typename I, typename RowMatrix>
CsrArrays<I> relax_interpolation(const RowMatrix& B, const std::vector<char>& is_c, CsrArrays<I> P, I n_c,
                                 int sweeps, double truncate) {
  static_assert(RowMatrix::IsRowMajor, "relax_interpolation reads B's rows");
  const I n = static_cast<I>(B.rows());
  std::vector<I> coarse(static_cast<std::size_t>(n));  // a C point's column in P
  bool f_coupled = false;
  for (I i = 0, c = 0; i < n; ++i) {
    coarse[i] = is_c[i] ? c++ : I(-1);
    if (!is_c[i] && !f_coupled)
      for (typename RowMatrix::InnerIterator it(B, i); it; ++it)
        if (it.index() != i && !is_c[it.index()] && it.value() != 0) f_coupled = true;
  }
  if (!f_coupled) sweeps = std::min(sweeps, 1);

  std::vector<double> acc(static_cast<std::size_t>(n_c), 0.0);
  std::vector<char> seen(static_cast<std::size_t>(n_c), 0);
  std::vector<I> cols;
  std::vector<std::pair<I, double>> row;
  for (int s = 0; s < sweeps; ++s) {
    CsrArrays<I> next;
    next.indptr.reserve(static_cast<std::size_t>(n) + 1);
    next.indices.reserve(P.indices.size());
    next.data.reserve(P.data.size());
    auto add = [&](I k, double v) {
      if (!seen[k]) { seen[k] = 1; cols.push_back(k); }
      acc[k] += v;
    };
    for (I i = 0; i < n; ++i) {
      if (is_c[i]) {
        next.indices.push_back(coarse[i]);
        next.data.push_back(1.0);
        next.indptr.push_back(static_cast<I>(next.indices.size()));
        continue;
      }
      double d = 0;
      for (typename RowMatrix::InnerIterator it(B, i); it; ++it) {
        const I j = static_cast<I>(it.index());
        if (j == i) d += it.value();
        else if (is_c[j]) add(coarse[j], it.value());
        else
          for (I e = P.indptr[j]; e < P.indptr[j + 1]; ++e) add(P.indices[e], it.value() * P.data[e]);
      }
      row.clear();
      for (const I k : cols) {
        if (acc[k] != 0) row.emplace_back(k, -acc[k] / d);
        acc[k] = 0;
        seen[k] = 0;
      }
      cols.clear();
      append_truncated(row, truncate, next);
    }
    P = std::move(next);
  }
  return P;
}

}  // namespace nrmicp::detail
