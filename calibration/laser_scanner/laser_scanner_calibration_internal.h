#pragma once

// Internal to calibration/laser_scanner: the joint refinement's residuals, public for its
// finite-difference test.

#include <Eigen/Core>
#include <vector>

namespace kinevis::calibration::internal {

// The rotating laser's residuals over stripe points p_i (in C, on the board) of stepper position
// position[i] ∈ [0, N): r_i = y_i + c_k z_i − b_y − d_y c_k (eq. 17 with eq. 8, algebraic: the
// distance from the plane times |(1, c_k)|), and J = ∂r/∂(b_y, d_y, c_1..c_N) (rows × (N + 2)).
void RotatingResiduals(const std::vector<Eigen::Vector3d>& points, const std::vector<int>& position,
                       double b_y, double d_y, const Eigen::VectorXd& c, Eigen::VectorXd* r,
                       Eigen::MatrixXd* J);

}  // namespace kinevis::calibration::internal
