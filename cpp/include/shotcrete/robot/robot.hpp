#pragma once
// The 8-DOF spraying manipulator (docs/architecture.md §7): URDF model loaded by kdl_parser, forward
// kinematics in the tunnel frame, 5-DOF inverse kinematics (nozzle position + spray axis, roll
// free) by damped least squares with null-space joint-limit avoidance and seeded random restarts,
// continuous joint paths along passes, a plain-KDL baseline and a reachability map.
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "shotcrete/config.hpp"
#include "shotcrete/deposition/deposition.hpp"  // NozzlePose

namespace shotcrete {

/// Path of the manipulator URDF bundled with the sources (data/shotcrete_manipulator.urdf).
std::string bundled_urdf_path();

/// One <collision> element of a link on the chain (URDF geometry: cylinders along their z axis,
/// boxes, spheres), in the frame of its link; or a box of a link named carrier* fixed to base_link
/// off the chain (the rig's carrier: `carrier`), in base_link's frame.
struct CollisionShape {
  enum class Kind { cylinder, box, sphere };
  std::string link;
  int frame = 0;  // index into Robot::link_frames(): 0 = base_link, k = the k-th segment of the chain
  Kind kind = Kind::cylinder;
  Eigen::Isometry3d origin = Eigen::Isometry3d::Identity();  // <collision><origin> in the link frame
  double radius_m = 0.0, length_m = 0.0;                      // cylinder; sphere: radius_m
  Eigen::Vector3d size_m = Eigen::Vector3d::Zero();           // box edges
  bool carrier = false;  // on a link fixed to base_link off the chain: the machine's body, whose place in a scan is the machine's own (machine_points)
};

/// A moving joint at a posture, in the tunnel frame: a point p of link frame f (f >= first_frame)
/// moves at axis x (p - point_m) per unit of a turning joint, axis per unit of a sliding one.
struct JointAxis {
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();  // unit
  Eigen::Vector3d point_m = Eigen::Vector3d::Zero();
  bool rotational = true;
  int first_frame = 1;  // the first link_frames() entry the joint moves
};

/// Serial chain base_link -> nozzle_tip read from a URDF. Joint order is the chain order.
/// Acceleration limits (URDF has none) come from `<shotcrete:limits joint=".." acceleration=".."
/// [neutral=".."]/>` elements of the same file; every movable joint must have one.
class Robot {
 public:
  /// Loads config.urdf_path (empty: the bundled URDF) and places base_link at
  /// config.base_position_m in the tunnel frame. Throws std::invalid_argument naming the problem
  /// (missing file, parse error, no base_link/nozzle_tip chain, missing limits).
  static Robot load(const RobotConfig& config);
  /// Same, from an explicit URDF file (used by Python with its installed copy).
  static Robot load_file(const std::string& urdf_path, const Eigen::Vector3d& base_position_m);
  /// Same, from URDF text.
  static Robot from_string(const std::string& urdf_xml, const Eigen::Vector3d& base_position_m);

  Robot(const Robot&);
  Robot& operator=(const Robot&);
  Robot(Robot&&) noexcept;
  Robot& operator=(Robot&&) noexcept;
  ~Robot();

  int dof() const;
  const std::vector<std::string>& joint_names() const;
  const std::vector<bool>& joint_is_prismatic() const;
  const Eigen::VectorXd& lower_limits() const;         // [rad] or [m]
  const Eigen::VectorXd& upper_limits() const;         // [rad] or [m]
  const Eigen::VectorXd& velocity_limits() const;      // [rad/s] or [m/s]
  const Eigen::VectorXd& acceleration_limits() const;  // [rad/s^2] or [m/s^2]
  /// base_link in the tunnel frame (pure translation).
  const Eigen::Isometry3d& base_pose() const;
  /// The same robot with base_link at base_position_m (place_base's candidates).
  Robot placed_at(const Eigen::Vector3d& base_position_m) const;
  /// The same robot with its carrier shapes (CollisionShape::carrier) turned to yaw_rad about
  /// base_link's z axis from where the URDF puts them (behind the arm along base_link's -x; the
  /// heading is set, not added: a turned robot turned again has the new heading). The job turns it
  /// to lie along the tunnel's axis (carrier_along_axis). Throws for a non-finite angle.
  Robot carrier_turned(double yaw_rad) const;
  /// The URDF path it was loaded from ("" for from_string).
  const std::string& urdf_path() const;

  /// nozzle_tip in the tunnel frame; its z axis is the spray direction. q must have dof() entries.
  Eigen::Isometry3d fk(const Eigen::VectorXd& q) const;
  /// World pose of base_link (index 0) and of the link at the tip of every chain segment (index k
  /// = segment k, the last one nozzle_tip): the frames CollisionShape::frame refers to.
  std::vector<Eigen::Isometry3d> link_frames(const Eigen::VectorXd& q) const;
  /// The same, and every moving joint's axis at q (in joint order): the Jacobian of any point on
  /// a link in the same pass, without a forward-kinematics call per joint.
  std::vector<Eigen::Isometry3d> link_frames(const Eigen::VectorXd& q, std::vector<JointAxis>& joints) const;
  const std::vector<std::string>& link_names() const;  // one per link_frames() entry
  /// The <collision> shapes of base_link and of every link on the chain (unsupported geometry,
  /// such as meshes, is an error at load time).
  const std::vector<CollisionShape>& collision_shapes() const;
  /// 6 x dof geometric Jacobian of nozzle_tip in the tunnel frame (rows: linear, angular).
  Eigen::MatrixXd jacobian(const Eigen::VectorXd& q) const;
  /// Ready posture (the `neutral` attribute of <shotcrete:limits>, else mid-range): default IK seed.
  Eigen::VectorXd neutral() const;
  /// The folded posture a job starts from (the trajectory's first sample; <shotcrete:limits
  /// stow=".."/>, default the neutral posture). The neutral posture stays the IK's preference.
  Eigen::VectorXd stow() const;
  /// True when every entry of q is within the limits (plus slack).
  bool within_limits(const Eigen::VectorXd& q, double slack = 1e-9) const;
  /// Boom lift pivot in the tunnel frame and an upper bound of the distance from it to the nozzle
  /// tip (used to tell "out of reach" from other failures).
  Eigen::Vector3d shoulder_position() const;
  double max_reach_m() const;

  struct Impl;  // KDL chain and limits (robot.cpp)
  const Impl& impl() const { return *impl_; }

 private:
  Robot();
  std::unique_ptr<Impl> impl_;
};

/// How the spray-axis part of the task error measures the turn from the spray axis z onto the
/// target axis t. Both vanish only where the axes agree and agree to third order in the angle near
/// there; their Gauss-Newton paths differ, so the same start reaches a slightly different point of
/// the redundant arm's self-motion (see track_joint_path).
enum class AxisError {
  RotationVector,  // exact: (z x t) / |z x t| times the angle; antiparallel turns about the nozzle x axis
  CrossProduct,    // z x t (length sin angle), with e(3) + 2 past 90 deg so that the far side is pushed
                   // away from the antipodal point where z x t vanishes
};

/// Error of the 5-DOF spraying task (roll about the spray axis free): the position error (3) and
/// the spray-axis turn (AxisError) expressed on the nozzle's x / y axes (2).
struct TaskError {
  Eigen::Matrix<double, 5, 1> e = Eigen::Matrix<double, 5, 1>::Zero();
  double position_m = 0.0;  // |position error|
  double angle_rad = 0.0;   // angle between the spray axis and the target axis (exact in either form)
};
/// Task error of a nozzle at position p with rotation R (spray axis = R's z column) towards the
/// target position and unit axis, all in one frame.
TaskError task_error(const Eigen::Vector3d& p, const Eigen::Matrix3d& R, const Eigen::Vector3d& target_position_m,
                     const Eigen::Vector3d& target_axis, AxisError form = AxisError::RotationVector);
/// The 5 x dof task Jacobian at rotation R (for either form): the linear rows of the 6 x dof
/// geometric Jacobian J and its angular rows on the nozzle's x / y axes (same frame as J).
Eigen::Matrix<double, 5, Eigen::Dynamic> task_jacobian(const Eigen::Matrix3d& R,
                                                       const Eigen::Matrix<double, 6, Eigen::Dynamic>& J);
/// Task error of the robot at q towards `target` (tunnel frame; the target axis need not be unit);
/// `jacobian` (optional) receives the task Jacobian. The IK (solve_ik_5dof) descends on the
/// rotation-vector form, the joint tracking (track_joint_path) on the cross-product form.
TaskError task_error(const Robot& robot, const Eigen::VectorXd& q, const NozzlePose& target,
                     Eigen::MatrixXd* jacobian = nullptr, AxisError form = AxisError::RotationVector);

struct IkResult {
  bool success = false;
  Eigen::VectorXd q;                 // the best configuration found (within limits)
  double position_error_m = 0.0;     // |p(q) - p_target|
  double angle_error_rad = 0.0;      // angle between the spray axis of q and the target axis
  int iterations = 0;                // total iterations over all restarts
  int restarts = 0;                  // restarts used
  std::string reason;                // empty on success, else why it failed
};

/// 5-DOF IK: nozzle_tip position and z axis; roll about the axis is free. Damped least squares
/// on the 5-row task Jacobian, joint limits by clamping plus a null-space pull towards mid-range
/// and towards the seed, then up to config.ik_max_restarts seeded random restarts. A result has
/// success = true only when q is within limits and the errors are within the config tolerances.
IkResult solve_ik_5dof(const Robot& robot, const NozzlePose& target, const Eigen::VectorXd& seed,
                       const RobotConfig& config);

/// Plain KDL baseline: ChainIkSolverPos_NR_JL (Newton-Raphson with joint limits, pseudo-inverse
/// velocity solver) on the full 6-DOF pose of nozzle_tip (tunnel frame), no restarts.
IkResult solve_ik_kdl_nr_jl(const Robot& robot, const Eigen::Isometry3d& target, const Eigen::VectorXd& seed,
                            const RobotConfig& config, int max_iterations = 500);

struct JointPath {
  std::vector<Eigen::VectorXd> q;       // one configuration per waypoint
  std::vector<double> position_error_m; // per waypoint
  std::vector<double> angle_error_rad;  // per waypoint
  double max_position_error_m = 0.0;
  double max_angle_error_rad = 0.0;
  double max_joint_step = 0.0;          // largest |q_i(k+1) - q_i(k)| over the path [rad or m]
  int inserted_substeps = 0;            // poses interpolated to keep the path continuous
};

/// IK for every waypoint of a pass, warm-started from the previous one. A solution whose joints
/// jump more than config.ik_max_joint_step from the previous waypoint is rejected and the pose is
/// reached through interpolated intermediate poses instead (no flips). Throws std::runtime_error
/// naming the waypoint index, its pose and the reason when a waypoint cannot be reached.
JointPath solve_path(const Robot& robot, const std::vector<NozzlePose>& waypoints, const Eigen::VectorXd& seed,
                     const RobotConfig& config);

/// Reachability of a half-cylinder bay: wall of radius radius_m around the tunnel axis
/// (y = z = 0), theta in [0, pi] from the +y springline over the crown, d in [0, bay_length_m]
/// along x; nozzle at standoff_m from the wall pointing along the outward normal.
struct ReachMap {
  double radius_m = 0.0;
  double standoff_m = 0.0;
  std::vector<double> theta_rad;        // n_theta
  std::vector<double> d_m;              // n_d
  std::vector<unsigned char> reached;   // n_theta x n_d, row-major
  std::vector<double> position_error_m; // n_theta x n_d
  std::vector<double> angle_error_rad;  // n_theta x n_d
  std::vector<double> min_limit_margin; // n_theta x n_d: smallest distance to a limit / range
  int n_reached = 0;
  int n_total = 0;
  double fraction() const { return n_total ? static_cast<double>(n_reached) / n_total : 0.0; }
};
ReachMap reachability_map(const Robot& robot, const RobotConfig& config, double radius_m, double standoff_m = 1.0,
                          double bay_length_m = 1.2, int n_theta = 61, int n_d = 13);

/// IK benchmark on random reachable poses (FK of random q within limits), seeded.
struct IkBenchmark {
  int samples = 0;
  int solved_5dof_neutral = 0;      // ours, from neutral()
  int solved_5dof_random_seed = 0;  // ours, from a random seed
  int solved_kdl_6dof = 0;          // KDL NR_JL on the full pose, from neutral()
  int solved_5dof_no_restart = 0;   // ours from neutral() without random restarts (ablation)
  int limit_violations = 0;         // returned successes outside the limits (must be 0)
  int tolerance_misses = 0;         // returned successes outside the tolerance (must be 0)
  std::vector<double> time_5dof_neutral_s, time_5dof_random_seed_s, time_kdl_6dof_s, time_5dof_no_restart_s;
  double max_position_error_m = 0.0;  // over our successes
  double max_angle_error_rad = 0.0;
};
IkBenchmark ik_benchmark(const Robot& robot, const RobotConfig& config, int samples, unsigned seed = 1);

}  // namespace shotcrete
