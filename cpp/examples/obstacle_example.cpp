// A membrane over an obstacle on the unit square: −Δu ≥ f, u ≥ ψ, (u − ψ)ᵀ(−Δu − f) = 0,
// as ICP(q, A, ζ) with A = the 5-point Laplacian (times h²), q = −h² f, ζ ≡ ψ (constant).
#include <nrmicp/nrmicp.hpp>

#include <cmath>
#include <cstdio>
#include <vector>

int main() {
  const int m = 100, n = m * m;
  const double h = 1.0 / (m + 1);
  std::vector<Eigen::Triplet<double>> t;
  Eigen::VectorXd q(n), psi(n);
  for (int j = 0; j < m; ++j)
    for (int i = 0; i < m; ++i) {
      const int r = j * m + i;
      t.emplace_back(r, r, 4.0);
      if (i > 0) t.emplace_back(r, r - 1, -1.0);
      if (i + 1 < m) t.emplace_back(r, r + 1, -1.0);
      if (j > 0) t.emplace_back(r, r - m, -1.0);
      if (j + 1 < m) t.emplace_back(r, r + m, -1.0);
      const double x = (i + 1) * h - 0.5, y = (j + 1) * h - 0.5;
      psi[r] = 0.3 - 2.0 * (x * x + y * y);  // a paraboloid cap
      q[r] = h * h * 8.0;                    // f = −8: a load pulling the membrane down
    }
  Eigen::SparseMatrix<double, Eigen::RowMajor> A(n, n);
  A.setFromTriplets(t.begin(), t.end());

  nrmicp::Options opt;
  opt.method = nrmicp::Method::NRMGS;
  opt.tol = 1e-10;
  opt.accelerate = nrmicp::Accelerate::Anderson;  // the unshifted Laplacian converges slowly without
  const auto r = nrmicp::solve(A, q, nrmicp::Zeta<int>::constant(psi), opt);
  int contact = 0;
  for (int i = 0; i < n; ++i) contact += (r.z[i] - psi[i] < 1e-9);
  std::printf("status: %s\niterations: %d\nRes: %.3e\ncontact points: %d of %d\ncholmod: %s, umfpack: %s\n",
              r.message.c_str(), r.nit, r.residual, contact, n, nrmicp::have_cholmod() ? "yes" : "no",
              nrmicp::have_umfpack() ? "yes" : "no");
  return r.success() && contact > 0 && contact < n ? 0 : 1;
}
