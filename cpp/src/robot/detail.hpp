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
  double carrier_yaw_rad = 0.0;  // the carrier shapes' turn from where the URDF puts them (carrier_turned)
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

// A joint's frame at position q, as KDL's Joint::pose gives it but without the rotation it caches
// inside the chain (a data race from several threads); kdl_parser's joints: axis joints, unit
// scale, no offset. What Robot::link_frames and Kin compose the chain from.
inline KDL::Frame joint_pose(const KDL::Joint& joint, double q) {
  return joint.getType() == KDL::Joint::RotAxis ? KDL::Frame(KDL::Rotation::Rot2(joint.JointAxis(), q), joint.JointOrigin())
                                                : joint.pose(q);
}

// Forward kinematics and the Jacobian of the chain, composed from the chain's joints and segment
// tips as Robot::link_frames composes them (no KDL solver: KDL's Joint::pose caches its last
// rotation in the chain, so its solvers are not safe from several threads, and its Jacobian solver
// changes the reference point of every column per segment). One pass gives the pose and the
// Jacobian (reference point the chain tip, both in the chain's base frame, as KDL's JntToJac).
struct Kin {
  const Robot::Impl& r;
  Eigen::Matrix<double, 6, Eigen::Dynamic> J;
  std::vector<Eigen::Vector3d> axis, origin;  // per joint: unit axis and a point on it, chain base frame
  std::vector<char> rotational;               // per joint: turns (else slides)
  explicit Kin(const Robot::Impl& impl)
      : r(impl), J(6, static_cast<Eigen::Index>(impl.chain.getNrOfJoints())), axis(impl.chain.getNrOfJoints()),
        origin(impl.chain.getNrOfJoints()), rotational(impl.chain.getNrOfJoints(), 0) {}
  // Pose of the chain tip (nozzle_tip) in the chain's base frame; with `jacobian` also J.
  void compose(const Eigen::VectorXd& q, Eigen::Vector3d& p, Eigen::Matrix3d& R, bool jacobian) {
    KDL::Frame f = KDL::Frame::Identity();
    std::size_t j = 0;
    for (std::size_t i = 0; i < r.chain.segments.size(); ++i) {
      const KDL::Joint& joint = r.chain.segments[i].getJoint();
      const bool moves = joint.getType() != KDL::Joint::None;
      const double qi = moves ? q[static_cast<Eigen::Index>(j)] : 0.0;
      if (moves && jacobian) {
        const KDL::Vector a = f.M * joint.JointAxis(), o = f * joint.JointOrigin();
        axis[j] = Eigen::Vector3d(a.x(), a.y(), a.z());
        origin[j] = Eigen::Vector3d(o.x(), o.y(), o.z());
        const auto t = joint.getType();
        rotational[j] = t == KDL::Joint::RotAxis || t == KDL::Joint::RotX || t == KDL::Joint::RotY || t == KDL::Joint::RotZ;
      }
      f = f * joint_pose(joint, qi) * r.segment_tip[i];
      if (moves) ++j;
    }
    p = Eigen::Vector3d(f.p.x(), f.p.y(), f.p.z());
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) R(a, b) = f.M(a, b);
    if (!jacobian) return;
    for (std::size_t k = 0; k < axis.size(); ++k) {
      const auto c = static_cast<Eigen::Index>(k);
      if (rotational[k]) {
        J.block<3, 1>(0, c) = axis[k].cross(p - origin[k]);
        J.block<3, 1>(3, c) = axis[k];
      } else {
        J.block<3, 1>(0, c) = axis[k];
        J.block<3, 1>(3, c).setZero();
      }
    }
  }
  // Pose of nozzle_tip in the base frame.
  void pose(const Eigen::VectorXd& q, Eigen::Vector3d& p, Eigen::Matrix3d& R) { compose(q, p, R, false); }
  const Eigen::Matrix<double, 6, Eigen::Dynamic>& jacobian(const Eigen::VectorXd& q) {
    Eigen::Vector3d p;
    Eigen::Matrix3d R;
    compose(q, p, R, true);
    return J;
  }
};

}  // namespace robot_detail
}  // namespace shotcrete
