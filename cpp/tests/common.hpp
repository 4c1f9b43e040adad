// Test problems shared by the C++ tests: Bai's matrices and ICPs with a known solution.
#pragma once

#include <nrmicp/nrmicp.hpp>

#include <Eigen/SparseCore>

#include <cmath>
#include <vector>

namespace testing {

template <typename I = int, int Order = Eigen::ColMajor>
using SpMat = Eigen::SparseMatrix<double, Order, I>;

/// Bai's matrix: A = Â + μI, Â = blocktridiag(−I, S, −I), S = tridiag(−1, 4, −1) (symmetric),
/// or Â = blocktridiag(−1.5I, S, −0.5I), S = tridiag(−1.5, 4, −0.5) (nonsymmetric); n = m².
template <typename I = int, int Order = Eigen::ColMajor>
SpMat<I, Order> bai(int m, double mu, bool symmetric) {
  const double lo = symmetric ? -1.0 : -1.5, up = symmetric ? -1.0 : -0.5;
  const int n = m * m;
  std::vector<Eigen::Triplet<double, I>> t;
  for (int b = 0; b < m; ++b)
    for (int i = 0; i < m; ++i) {
      const int r = b * m + i;
      t.emplace_back(r, r, 4.0 + mu);
      if (i > 0) t.emplace_back(r, r - 1, lo);
      if (i + 1 < m) t.emplace_back(r, r + 1, up);
      if (b > 0) t.emplace_back(r, r - m, lo);
      if (b + 1 < m) t.emplace_back(r, r + m, up);
    }
  SpMat<I, Order> A(n, n);
  A.setFromTriplets(t.begin(), t.end());
  A.makeCompressed();
  return A;
}

/// A known solution: z* alternates between g* > 0 (w* = 0) and g* = 0 (w* > 0).
struct Known {
  Eigen::VectorXd z, w, g;
};

inline Known known_solution(Eigen::Index n) {
  Known k{Eigen::VectorXd(n), Eigen::VectorXd(n), Eigen::VectorXd(n)};
  for (Eigen::Index i = 0; i < n; ++i) {
    const bool active = (i % 3 == 1);
    k.g[i] = active ? 0.0 : 1.0 + 0.5 * std::sin(double(i));
    k.w[i] = active ? 0.5 + 0.25 * std::cos(double(i)) : 0.0;
  }
  return k;
}

}  // namespace testing
