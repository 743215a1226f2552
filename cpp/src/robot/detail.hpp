#pragma once
// Internals shared by the robot sources (not part of the public headers): the KDL chain and
// limits behind Robot, conversions and per-call KDL solver state.
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <kdl/chain.hpp>
#include <kdl/chainfksolverpos_recursive.hpp>
#include <kdl/chainjnttojacsolver.hpp>
#include <kdl/frames.hpp>
#include <kdl/jacobian.hpp>
#include <kdl/jntarray.hpp>

#include "shotcrete/robot/robot.hpp"

namespace shotcrete {

struct Robot::Impl {
  KDL::Chain chain;
  std::vector<std::string> names;
  std::vector<bool> prismatic;
  Eigen::VectorXd lower, upper, velocity, acceleration, neutral, stow;
  Eigen::Isometry3d base = Eigen::Isometry3d::Identity();
  std::string path;
  Eigen::Vector3d shoulder_in_base{0, 0, 0};
  double max_reach_m = 0.0;
  std::vector<std::string> link_names;  // base_link, then the child link of each chain segment
  std::vector<CollisionShape> shapes;
  // Per chain segment: the frame from its joint to its tip. KDL's Joint::pose caches the last
  // rotation in the chain itself, so link_frames (run from several threads by check_clearance)
  // composes the joints' poses from these without it.
  std::vector<KDL::Frame> segment_tip;
};

namespace robot_detail {

KDL::JntArray to_kdl(const Eigen::VectorXd& q);
KDL::Frame to_kdl(const Eigen::Isometry3d& t);
/// Throws std::invalid_argument unless q has one finite entry per joint (`what` names q).
void check_q(const Robot& robot, const Eigen::VectorXd& q, const char* what);
/// Angle between two directions [rad].
double axis_angle(const Eigen::Vector3d& a, const Eigen::Vector3d& b);

// Per-call KDL solver state (KDL solvers are not thread-safe; construction is cheap).
struct Kin {
  const Robot::Impl& r;
  KDL::ChainFkSolverPos_recursive fk;
  KDL::ChainJntToJacSolver jac;
  KDL::JntArray qk;
  KDL::Frame frame;
  KDL::Jacobian J;
  explicit Kin(const Robot::Impl& impl)
      : r(impl), fk(impl.chain), jac(impl.chain), qk(impl.chain.getNrOfJoints()), J(impl.chain.getNrOfJoints()) {}
  // Pose of nozzle_tip in the base frame.
  void pose(const Eigen::VectorXd& q, Eigen::Vector3d& p, Eigen::Matrix3d& R) {
    qk.data = q;
    fk.JntToCart(qk, frame);
    for (int i = 0; i < 3; ++i) {
      p(i) = frame.p(i);
      for (int j = 0; j < 3; ++j) R(i, j) = frame.M(i, j);
    }
  }
  const Eigen::Matrix<double, 6, Eigen::Dynamic>& jacobian(const Eigen::VectorXd& q) {
    qk.data = q;
    jac.JntToJac(qk, J);
    return J.data;
  }
};

}  // namespace robot_detail
}  // namespace shotcrete
