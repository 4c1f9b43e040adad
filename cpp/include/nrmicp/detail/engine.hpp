// nrmicp — the engine of the Newton driver: what a level needs of its matrix, as free operations
// overloaded by the matrix type (AMGCL's backend shape). The driver (newton_level.hpp,
// newton_step.hpp, globalization.hpp, newton_run.hpp, newton.hpp) is written once against them;
// this file is the Eigen/SuiteSparse engine, cpp/include/nrmicp/petsc/engine.hpp the PETSc one.
//   comm_of(A)                     the global reductions (detail/comm.hpp)
//   row_offset(A)                  the global index of the first row this process owns
//   check_operator(A)              what the engine needs of A (throws naming a row of this process)
//   global_rows(A), global_cols(A) the sizes of the whole matrix
//   multiply(A, v, out)            out = A v (this process's rows); multiply_add: out += A v
//   diagonal_block(A)              the rows and columns this process owns, as a serial matrix (the
//                                  stationary members' splitting: multisplitting, solver.hpp)
//   abs_multiply_add(A, v, out)    out += |A| v
//   sweep_rows(A, q, y, k, box)    k symmetric projected Gauss–Seidel sweeps on the rows owned
//   galerkin(P, A), transpose(P)   the coarse operator PᵀAP and R = Pᵀ of a hierarchy level
//   inject_bounds(P, b, none)      a coarse level's bounds (box.hpp)
//   Engine<M>::System, ::Fallback  the reduced step's solve and the fallback member of a level
#pragma once

#include "comm.hpp"
#include "galerkin.hpp"
#include "sparse_product.hpp"

#include <Eigen/SparseCore>

namespace nrmicp {
template <typename MatrixType>
class Solver;
}  // namespace nrmicp

namespace nrmicp::detail {

/// A reduced system's Krylov solve without an absolute target stops at ‖b − Kz‖ ≤ this × ‖b‖ (both engines).
inline constexpr double kKrylovRtol = 1e-12;

template <typename StorageIndex>
class ActiveSetSystem;

/// The serial engine's matrices: Eigen sparse matrices (and Maps of them), every row owned.
template <typename Derived>
const Comm& comm_of(const Eigen::SparseMatrixBase<Derived>&) {
  return serial_comm();
}
template <typename Derived>
Eigen::Index row_offset(const Eigen::SparseMatrixBase<Derived>&) {
  return 0;
}
/// What an engine needs of A beyond the member's own rules (throws naming this process's offending row):
/// nothing serially; the PETSc engine's, petsc/engine.hpp. Run under collective_check by the constructors.
template <typename Derived>
void check_operator(const Eigen::SparseMatrixBase<Derived>&) {}
/// The rows and columns of the whole matrix (every process's).
template <typename Derived>
Eigen::Index global_rows(const Eigen::SparseMatrixBase<Derived>& A) {
  return A.rows();
}
template <typename Derived>
Eigen::Index global_cols(const Eigen::SparseMatrixBase<Derived>& A) {
  return A.cols();
}
template <typename Derived>
void multiply(const Eigen::SparseMatrixBase<Derived>& A, const Eigen::VectorXd& v, Eigen::VectorXd& out) {
  out.noalias() = A.derived() * v;
}
template <typename Derived>
void multiply_add(const Eigen::SparseMatrixBase<Derived>& A, const Eigen::VectorXd& v, Eigen::VectorXd& out) {
  out.noalias() += A.derived() * v;
}
/// Every row and column is this process's: A itself.
template <typename Derived>
const Derived& diagonal_block(const Eigen::SparseMatrixBase<Derived>& A) {
  return A.derived();
}
/// diagonal_block of any engine's matrix (found by argument-dependent lookup): A itself serially (a
/// reference), a view of the block otherwise.
template <typename MatrixType>
decltype(auto) block_of(const MatrixType& A) {
  return diagonal_block(A);
}
template <typename Derived, typename V>
void abs_multiply_add(const Eigen::SparseMatrixBase<Derived>& A, const V& v, Eigen::VectorXd& out) {
  out.noalias() += A.derived().cwiseAbs() * v;
}
template <typename StorageIndex>
Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex> transpose(
    const Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>& P) {
  return P.transpose();
}
/// PᵀAP with R = Pᵀ given (the level holds it).
template <typename StorageIndex, typename MatrixType>
Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex> galerkin(
    const Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>& R, const MatrixType& A,
    const Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>& P) {
  return product(R, product(A, P));
}

/// The types a level of the Newton driver takes from its engine: the matrices of its hierarchy
/// (`Coarse`: P, R, the coarse operators, an affine ζ's B) and the reduced step's `System`.
template <typename MatrixType>
struct Engine {
  using StorageIndex = typename MatrixType::StorageIndex;
  using Coarse = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  using System = ActiveSetSystem<StorageIndex>;
  using Level = detail::Level<StorageIndex>;          ///< P, R = Pᵀ and the coarse operator (multigrid.hpp)
  using Hierarchy = detail::Hierarchy<StorageIndex>;  ///< the levels below one
  using Fallback = Solver<MatrixType>;                ///< the fallback member (nrm) of a level
  /// Whether the engine has every ζ strategy: an affine ζ's full system, a sparse ζ′ that couples rows.
  static constexpr bool serial = true;
};

}  // namespace nrmicp::detail
