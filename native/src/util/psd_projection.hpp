// Projection of a small dense symmetric matrix onto the positive semidefinite cone: eigenvalues below zero
// are set to zero (the nearest PSD matrix in the Frobenius norm). Applied per element to the exact Hessian,
// it gives the "projected Newton" matrix of Teran et al. 2005 and IPC (Li et al. 2020): exact where the
// element is stable, never indefinite.
#pragma once
#include <Eigen/Eigenvalues>

namespace drapelab {

// H: N x N row-major (symmetric), projected in place.
template <int N>
void project_psd(double* H) {
  Eigen::Map<Eigen::Matrix<double, N, N, Eigen::RowMajor>> M(H);
  const Eigen::Matrix<double, N, N> S = 0.5 * (M + M.transpose());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, N, N>> eig(S);
  const auto& lambda = eig.eigenvalues();
  if (lambda.minCoeff() >= 0) {
    M = S;
    return;
  }
  const Eigen::Matrix<double, N, 1> clamped = lambda.cwiseMax(0.0);
  M = eig.eigenvectors() * clamped.asDiagonal() * eig.eigenvectors().transpose();
}

}  // namespace drapelab
