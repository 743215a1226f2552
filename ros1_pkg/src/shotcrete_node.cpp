// shotcrete_node: the planner on the core library, driven from ROS.
//
// Input:     ~cloud_in (sensor_msgs/PointCloud2, tunnel frame), or ~cloud_file, or ~synthetic + ~seed.
// Services:  ~plan (std_srvs/Trigger: success + the job summary as JSON, the core's JobSummary, as
//            in report.json), ~execute (success + a one-line summary), ~rescan (shotcrete_ros/Rescan:
//            the after-scan's file, empty for the synthetic after-scan; success + the status as JSON).
// Rescan:    ~after_scan (PointCloud2) or ~rescan: the after-scan registered to the before-scan on
//            reference areas, the layer measured per cell, the flow calibrated and the corrective
//            round planned, all by the core's rescan_job (as `shotcrete rescan`); published on
//            ~thickness (PointCloud2 per measured cell, intensity = layer [m]), ~corrective_passes
//            (MarkerArray, as ~passes) and ~rescan_status (String: the status JSON, or the error).
//            The corrective round then becomes the node's job: ~execute sprays it (on the
//            registered after-scan's wall, with the calibrated flow), and a rescan after that
//            measures it against the after-scan. rescan.reference mask reads ~rescan_mask_file.
// Published: ~cloud (PointCloud2, TD as intensity and rgb; republished while concrete is deposited),
//            ~grid_levels, ~passes (MarkerArray), ~summary (String: the plan's JSON summary),
//            ~clearance (MarkerArray: each link's collision shapes at the posture of its least
//            distance to the wall, red when closer than its margin, and the wall's closest point),
//            /joint_states, /tf_static.
// Config:    ~config (YAML; default the repository's config/default.yaml), and every
//            ~<section>/<key> of the config field table overrides that one value.
#include <geometry_msgs/TransformStamped.h>
#include <ros/ros.h>
#include <sensor_msgs/JointState.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>
#include <tf2_msgs/TFMessage.h>
#include <visualization_msgs/MarkerArray.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cmath>
#include <iomanip>
#include <memory>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <thread>

#include "ros_conversions.hpp"
#include "shotcrete/io/survey.hpp"
#include "shotcrete_ros/Rescan.h"
#include "shotcrete/pipeline/rescan_job.hpp"
#include "shotcrete/collision/clearance.hpp"
#include "shotcrete/pipeline/arm_plan.hpp"
#include "shotcrete/pipeline/executed_deposit.hpp"
#include "shotcrete/pipeline/job_summary.hpp"
#include "shotcrete/config.hpp"
#include "shotcrete/deposition/deposition.hpp"
#include "shotcrete/deposition/wall.hpp"
#include "shotcrete/surface/grid.hpp"
#include "shotcrete/io/io.hpp"
#include "shotcrete/planning/planner.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/surface/preprocess.hpp"
#include "shotcrete/surface/surface.hpp"
#include "shotcrete/io/synth.hpp"
#include "shotcrete/timing/timing.hpp"

namespace shotcrete_ros {
namespace {

using shotcrete::Cloud;
using shotcrete::Config;
using shotcrete::Plan;
using shotcrete::Surface;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// A job's problems on one line ("message [code]; ..."); empty when the plan is right.
std::string problems_text(const shotcrete::JobSummary& job) {
  std::string text;
  for (const auto& p : job.problems) text += (text.empty() ? "" : "; ") + p.message + " [" + p.code + "]";
  return text;
}

std::string levels_text(const std::map<int, int>& counts) {
  std::ostringstream s;
  s << "{";
  bool first = true;
  for (const auto& [level, n] : counts) {
    if (level == shotcrete::kNoDataLevel) continue;
    s << (first ? "" : ", ") << level << ": " << n;
    first = false;
  }
  s << "}";
  return s.str();
}

/// A number for the status JSON (null when not finite).
std::string num(double v, int precision = 3) {
  if (!std::isfinite(v)) return "null";
  std::ostringstream s;
  s << std::fixed << std::setprecision(precision) << v;
  return s.str();
}

/// `text` as a JSON string (quotes, backslashes and control characters escaped).
std::string json_string(const std::string& text) {
  std::string out = "\"";
  for (char c : text) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", static_cast<unsigned>(static_cast<unsigned char>(c)));
      out += buf;
    } else {
      out += c;
    }
  }
  return out + "\"";
}

/// {"cells", "mean", "min", "max", "rms"} of the finite values, in mm.
std::string stats_mm(const Eigen::VectorXd& values_m) {
  int n = 0;
  double sum = 0, sq = 0, lo = INFINITY, hi = -INFINITY;
  for (Eigen::Index i = 0; i < values_m.size(); ++i) {
    const double v = values_m[i] * 1000.0;
    if (!std::isfinite(v)) continue;
    ++n, sum += v, sq += v * v, lo = std::min(lo, v), hi = std::max(hi, v);
  }
  if (n == 0) return "{\"cells\": 0}";
  return "{\"cells\": " + std::to_string(n) + ", \"mean\": " + num(sum / n) + ", \"min\": " + num(lo) +
         ", \"max\": " + num(hi) + ", \"rms\": " + num(std::sqrt(sq / n)) + "}";
}

geometry_msgs::Point point_msg(const Eigen::Vector3d& p) {
  geometry_msgs::Point m;
  m.x = p.x();
  m.y = p.y();
  m.z = p.z();
  return m;
}

}  // namespace

class ShotcreteNode {
 public:
  ShotcreteNode(ros::NodeHandle nh, ros::NodeHandle pnh) : nh_(nh), pnh_(pnh) {
    // SHOTCRETE_SOURCE_DIR: the repository root, from the core library's target.
    const std::string default_config = std::string(SHOTCRETE_SOURCE_DIR) + "/config/default.yaml";
    pnh_.param<std::string>("config", config_path_, default_config);
    config_ = shotcrete::load_config(config_path_);
    // ~seed is the short form of ~synth/seed (the per-key override below wins if both are set).
    int seed = -1;
    if (pnh_.getParam("seed", seed)) {
      if (seed < 0) throw std::invalid_argument("~seed must not be negative, got " + std::to_string(seed));
      config_.synth.seed = static_cast<std::uint64_t>(seed);
    }
    const auto overridden = apply_param_overrides(pnh_, config_);
    pnh_.param<std::string>("frame_id", frame_id_, "tunnel");
    pnh_.param<std::string>("survey_frame_id", survey_frame_id_, "survey");  // parent of frame_id in tf_static
    pnh_.param<std::string>("urdf", urdf_path_,
                            config_.robot.urdf_path.empty() ? shotcrete::bundled_urdf_path() : config_.robot.urdf_path);
    pnh_.param("execute_time_scale", time_scale_, 1.0);
    pnh_.param("execute_max_wall_s", max_wall_s_, 0.0);  // > 0: raise the time scale to fit
    pnh_.param("joint_state_rate_hz", joint_rate_hz_, 50.0);
    pnh_.param("cloud_rate_hz", cloud_rate_hz_, 2.0);
    pnh_.param("td_color_max_m", td_color_max_m_, 0.0);  // 0 = the largest TD of the scan
    pnh_.param("max_points", max_points_, 20000000);     // larger clouds on ~cloud_in are refused
    pnh_.param<std::string>("rescan_mask_file", rescan_mask_file_, "");  // rescan.reference mask: the mask cloud
    std::vector<double> pose;
    if (pnh_.getParam("rescan_initial_pose", pose)) {  // 16 numbers, row-major: after -> before start
      if (pose.size() != 16) throw std::invalid_argument("~rescan_initial_pose needs 16 numbers (a 4x4 row-major)");
      for (int i = 0; i < 16; ++i) initial_pose_(i / 4, i % 4) = pose[i];
      const Eigen::Matrix3d R = initial_pose_.topLeftCorner<3, 3>();
      if (!initial_pose_.allFinite() || (R * R.transpose() - Eigen::Matrix3d::Identity()).norm() > 1e-6 ||
          (initial_pose_.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).norm() > 1e-9)
        throw std::invalid_argument("~rescan_initial_pose is not a rigid transform");
    }
    if (max_points_ < 1) throw std::invalid_argument("~max_points must be >= 1, got " + std::to_string(max_points_));
    if (!(time_scale_ > 0) || !(joint_rate_hz_ >= 1) || !(cloud_rate_hz_ > 0))
      throw std::invalid_argument("~execute_time_scale and ~cloud_rate_hz must be > 0, ~joint_state_rate_hz >= 1");
    std::ostringstream ov;
    for (const auto& k : overridden) ov << " " << k;
    ROS_INFO("config %s%s%s", config_path_.c_str(), overridden.empty() ? "" : ", overridden:", ov.str().c_str());

    robot_ = std::make_unique<shotcrete::Robot>(
        shotcrete::Robot::load_file(urdf_path_, config_.robot.base_position_m));
    q_current_ = robot_->stow();  // where every trajectory starts
    joint_names_ = robot_->joint_names();
    job_config_ = config_;
    pnh_.setParam("local_origin_m", std::vector<double>{0.0, 0.0, 0.0});

    cloud_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("cloud", 1, true);
    levels_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("grid_levels", 1, true);
    passes_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("passes", 1, true);
    clearance_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("clearance", 1, true);
    thickness_pub_ = pnh_.advertise<sensor_msgs::PointCloud2>("thickness", 1, true);
    corrective_pub_ = pnh_.advertise<visualization_msgs::MarkerArray>("corrective_passes", 1, true);
    rescan_status_pub_ = pnh_.advertise<std_msgs::String>("rescan_status", 1, true);
    summary_pub_ = pnh_.advertise<std_msgs::String>("summary", 1, true);
    joint_pub_ = nh_.advertise<sensor_msgs::JointState>("joint_states", 10);
    tf_static_pub_ = nh_.advertise<tf2_msgs::TFMessage>("tf_static", 1, true);
    publish_base_transform();

    cloud_sub_ = pnh_.subscribe("cloud_in", 2, &ShotcreteNode::on_cloud, this);
    plan_srv_ = pnh_.advertiseService("plan", &ShotcreteNode::on_plan, this);
    execute_srv_ = pnh_.advertiseService("execute", &ShotcreteNode::on_execute, this);
    after_sub_ = pnh_.subscribe("after_scan", 1, &ShotcreteNode::on_after_scan, this);
    rescan_srv_ = pnh_.advertiseService("rescan", &ShotcreteNode::on_rescan, this);
    // The arm is shown at rest until an execution streams the trajectory.
    idle_timer_ = nh_.createWallTimer(ros::WallDuration(0.1), [this](const ros::WallTimerEvent&) {
      if (!executing_) publish_joints(q_current_, ros::Time::now());
    });
  }

  /// Startup input: ~cloud_file or ~synthetic. Returns false when neither is set.
  bool load_initial_cloud() {
    std::string file;
    bool synthetic = false;
    pnh_.param<std::string>("cloud_file", file, "");
    pnh_.param("synthetic", synthetic, false);
    if (!file.empty() && synthetic) throw std::invalid_argument("set either ~cloud_file or ~synthetic, not both");
    auto cloud = std::make_shared<Cloud>();
    std::string source;
    std::shared_ptr<const shotcrete::SyntheticBay> bay;
    std::shared_ptr<const Cloud> before_scan;
    if (!file.empty()) {
      *cloud = shotcrete::read_cloud(file);
      source = file;
    } else if (synthetic) {
      bay = std::make_shared<shotcrete::SyntheticBay>(shotcrete::make_synthetic_bay(config_.synth));
      // Planned on the bay's wall (as `shotcrete demo`); re-scans register on the scan with its
      // surroundings (synth.context_*, as `shotcrete synth` writes the before-scan).
      *cloud = bay->sample(config_.grid.cell_size_m);
      before_scan = std::make_shared<Cloud>(bay->sample_scan(config_.grid.cell_size_m));
      source = "synthetic bay (seed " + std::to_string(config_.synth.seed) + ")";
    } else {
      return false;
    }
    std::string error;
    std::lock_guard<std::mutex> work(work_mutex_);  // the spinner already serves ~plan
    if (!set_cloud(cloud, source, error, before_scan)) throw std::invalid_argument("cloud from " + source + ": " + error);
    std::lock_guard<std::mutex> lock(state_mutex_);
    synthetic_bay_ = bay;
    return true;
  }

  /// Plans the current surface; fills `summary` with the job summary (JSON). Returns false (with
  /// the reason) on failure.
  bool plan(std::string& summary) {
    std::unique_lock<std::mutex> work(work_mutex_, std::try_to_lock);
    if (!work.owns_lock()) {
      summary = "busy: a plan or an execution is running";
      return false;
    }
    std::shared_ptr<const Surface> surface;
    long points_in = 0;
    shotcrete::Config config;  // config_ in the cloud's local frame
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      surface = surface_;
      points_in = points_in_;
      config = job_config_;
    }
    if (!surface) {
      summary = "no cloud yet: publish one on " + pnh_.resolveName("cloud_in") + ", or set ~synthetic or ~cloud_file";
      return false;
    }
    const auto t0 = Clock::now();
    auto plan = std::make_shared<Plan>();
    std::shared_ptr<shotcrete::TimedTrajectory> trajectory;
    std::shared_ptr<shotcrete::ExecutedDeposit> executed;
    shotcrete::JobSummary job;
    // Every plan starts from the configured base (a plan before may have placed robot_ elsewhere).
    const shotcrete::Robot configured = robot_->placed_at(config.robot.base_position_m);
    std::unique_ptr<shotcrete::Robot> placed;
    try {
      // Planned for the arm (speeds its joints can follow), timed, re-planned where needed.
      double last_report = -1.0;
      shotcrete::ArmPlan arm = shotcrete::plan_for_arm(*surface, config, configured, [&](const std::string& stage, double fraction) {
        const double t = seconds_since(t0);
        if (t - last_report >= 2.0) {
          ROS_INFO("planning: %s %.0f %%", stage.c_str(), 100.0 * fraction);
          last_report = t;
        }
      });
      job = shotcrete::summarise_job(*surface, arm, configured, config, {points_in});
      // robot.place_base: the arm stands where the plan placed it (room to slew every way), from
      // here on for the execution, the re-scan and the base's transform.
      placed = std::make_unique<shotcrete::Robot>(shotcrete::placed_robot(configured, arm.base_placement));
      if (arm.base_placement.moved)
        ROS_WARN("robot.base_position_m lacks room (%.2f m of %.2f m to slew every way, %.2f m for the base): base "
                 "placed %.1f m along the axis (~summary base_placement)", arm.base_placement.configured_room_m,
                 config.clearance.via_allowance_m, arm.base_placement.configured_base_room_m, arm.base_placement.shift_m);
      *plan = std::move(arm.plan);
      // The plan stays usable (markers, summary) without a trajectory; only ~execute needs it.
      if (arm.trajectory) trajectory = std::make_shared<shotcrete::TimedTrajectory>(std::move(*arm.trajectory));
      if (arm.executed) executed = std::make_shared<shotcrete::ExecutedDeposit>(std::move(*arm.executed));
    } catch (const std::exception& e) {
      summary = std::string("planning failed: ") + e.what();
      return false;
    }
    robot_ = std::move(placed);  // work_mutex_ held: no execution or re-scan runs
    publish_base_transform();
    summary = job.to_json();
    // One line in the log; the whole summary goes to ~summary and the service response.
    const std::string timed = job.trajectory ? "trajectory " + std::to_string(job.trajectory->duration_s) + " s"
                                             : "no trajectory: " + job.ik.error;
    ROS_INFO("plan in %.1f s: %d rounds, %d passes, spray %.0f s, %s (summary on %s)", seconds_since(t0),
             job.rounds, job.passes, job.spray_time_s, timed.c_str(), summary_pub_.getTopic().c_str());
    const std::string problems = problems_text(job);
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      plan_ = plan;
      trajectory_ = trajectory;
      executed_ = executed;
      plan_problems_ = problems;
    }
    publish_passes(*surface, *plan, passes_pub_);
    if (job.clearance && trajectory) publish_clearance(*job.clearance, *trajectory);
    else clearance_pub_.publish(visualization_msgs::MarkerArray{});
    std_msgs::String msg;
    msg.data = summary;
    summary_pub_.publish(msg);
    // A plan that is not right (summary status / problems) stays visible but is no success.
    for (const auto& p : job.problems) ROS_WARN("plan not executable: %s [%s]", p.message.c_str(), p.code.c_str());
    return job.status == "ok";
  }

  /// Streams the timed trajectory as /joint_states and deposits concrete on the cloud as it goes
  /// (the pump's flow of the executed deposit, on the scan); the final wall and its levels are the
  /// core's executed deposit (execute_deposit, round by round on the moved wall), as in ~summary.
  bool execute(std::string& summary) {
    std::unique_lock<std::mutex> work(work_mutex_, std::try_to_lock);
    if (!work.owns_lock()) {
      summary = "busy: a plan or an execution is running";
      return false;
    }
    std::shared_ptr<const Surface> surface;
    std::shared_ptr<const shotcrete::TimedTrajectory> traj;
    std::shared_ptr<const Plan> plan;
    std::shared_ptr<const shotcrete::ExecutedDeposit> executed;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      surface = surface_;
      traj = trajectory_;
      executed = executed_;
      plan = plan_;
      if (!plan_) {
        summary = "no plan: call " + pnh_.resolveName("plan") + " first";
        return false;
      }
      // A plan that is not right (a collision, limits broken, cells unreachable) is shown, never run.
      if (!plan_problems_.empty()) {
        summary = "the plan is not executable: " + plan_problems_;
        return false;
      }
    }
    if (!traj || traj->size() < 2 || !executed) {
      summary = "the plan has no timed trajectory (see the plan summary)";
      return false;
    }
    executing_ = true;  // the idle publisher stops: only trajectory samples from here on
    struct Reset {
      std::atomic<bool>& flag;
      ~Reset() { flag = false; }
    } reset{executing_};
    const auto model = spot_model();
    const shotcrete::SurfaceIndex index(surface->cloud);
    const std::vector<double> dwell = shotcrete::flow_dwells(executed->flow, traj->t_s);
    Eigen::VectorXd deposited = Eigen::VectorXd::Zero(surface->cloud.size());
    const Eigen::VectorXd td0 = shotcrete::point_td(surface->cloud, surface->axis, surface->profile);

    const auto t0 = Clock::now();
    std::size_t next = 0;          // first sample not yet deposited
    std::size_t published = 0;
    ros::WallRate rate(joint_rate_hz_);
    double last_cloud_wall = -1e9;
    const double duration = traj->t_s.back();
    const double time_scale =
        max_wall_s_ > 0 ? std::max(time_scale_, (duration - traj->t_s.front()) / max_wall_s_) : time_scale_;
    while (ros::ok()) {
      const double wall = seconds_since(t0);
      const double t = std::min(duration, traj->t_s.front() + wall * time_scale);
      // Sample at or after t: deposit every spraying sample up to it.
      const auto it = std::lower_bound(traj->t_s.begin(), traj->t_s.end(), t);
      const std::size_t k = std::min<std::size_t>(traj->size() - 1, static_cast<std::size_t>(it - traj->t_s.begin()));
      deposit(model, index, *traj, dwell, next, k + 1, deposited);
      next = k + 1;
      publish_joints(interpolate(*traj, t, k), ros::Time::now());
      ++published;
      const bool done = t >= duration;
      if (done) {  // the core's executed deposit, round by round on the moved wall
        const Cloud& sprayed = executed->wall.surface.cloud;
        publish_cloud(sprayed.xyz, shotcrete::point_td(sprayed, surface->axis, surface->profile));
      } else if (wall - last_cloud_wall >= 1.0 / cloud_rate_hz_) {
        publish_cloud(surface->cloud.xyz, td0 - deposited);
        last_cloud_wall = wall;
      }
      if (done) break;
      rate.sleep();
    }
    q_current_ = traj->q.back();
    const Eigen::VectorXd td1 = shotcrete::point_td(executed->wall.surface.cloud, surface->axis, surface->profile);
    // Levels of the sprayed wall: the executed deposit's (the summary's levels_after).
    const Surface& sprayed = executed->wall.surface;
    publish_levels(sprayed);
    std::ostringstream s;
    s << std::fixed << std::setprecision(3) << "executed " << traj->duration_s << " s of trajectory in "
      << seconds_since(t0) << " s wall (time scale " << time_scale << "), " << published
      << " joint states; mean TD " << td0.mean() * 1000 << " -> " << td1.mean() * 1000 << " mm";
    if (plan->sprayed_cloud.size() == surface->cloud.size())  // the planner's own simulation, for comparison
      s << " (plan predicted "
        << shotcrete::point_td(plan->sprayed_cloud, surface->axis, surface->profile).mean() * 1000 << " mm)";
    s << ", deposited max " << executed->deposited_m.maxCoeff() * 1000 << " mm, levels_after="
      << levels_text(shotcrete::level_counts(sprayed.levels));
    summary = s.str();
    if (!ros::ok()) return false;
    // What ~rescan measures against: the executed deposit per cell of the grid planned on.
    auto job = std::make_shared<SprayedJob>();
    job->surface = surface;
    job->deposit_m = std::make_shared<Eigen::VectorXd>(surface->grid.td_m - executed->td_after_m);
    std::lock_guard<std::mutex> lock(state_mutex_);
    job->before = before_scan_, job->bay = synthetic_bay_, job->config = job_config_;
    job->corrective = job_is_corrective_;
    sprayed_ = job;
    return true;
  }

  /// The loop on the executed job (the core's rescan_job, as `shotcrete rescan`): `after` (nullptr:
  /// the synthetic after-scan of the executed deposit, with ~synthetic) registered to the
  /// before-scan, the layer per cell, the flow factor and the corrective round; publishes
  /// ~thickness, ~corrective_passes and ~rescan_status. `status`: the status JSON, or the reason.
  bool rescan(const Cloud* after_in, const std::string& source, std::string& status) {
    std::unique_lock<std::mutex> work(work_mutex_, std::try_to_lock);
    if (!work.owns_lock()) {
      status = "busy: a plan, an execution or a rescan is running";
      return false;
    }
    std::shared_ptr<const SprayedJob> job;
    Eigen::Vector3d origin;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      job = sprayed_, origin = local_origin_m_;
      if (!surface_ || !before_scan_) {
        status = "no before-scan: publish one on " + pnh_.resolveName("cloud_in") + ", or set ~synthetic or ~cloud_file";
        return false;
      }
    }
    if (!job) {
      status = "nothing sprayed yet: call " + pnh_.resolveName("plan") + " and " + pnh_.resolveName("execute") +
               " first (the rescan measures what the executed plan laid)";
      return false;
    }
    const Surface* surface = job->surface.get();
    const shotcrete::Config& config = job->config;  // config_ in the before-scan's local frame (calibrated: a corrective round)
    const auto t0 = Clock::now();
    Cloud after;
    if (after_in != nullptr) {
      after = *after_in;  // in the before-scan's frame: into its local frame too
      if (!origin.isZero(0.0)) after.xyz.rowwise() -= (origin / config.io.unit_scale).transpose();
    } else if (job->bay) {
      after = shotcrete::make_after_scan(*job->bay, surface->grid, job->deposit_m->unaryExpr([](double v) {
                                           return std::isfinite(v) ? v : 0.0;
                                         }), config_).cloud;
    } else {
      status = job->corrective
                   ? "no after-scan file given; the synthetic after-scan is of the synthetic bay's first job, not of a "
                     "corrective round: give the after-scan's file or publish it on " + pnh_.resolveName("after_scan")
                   : "no after-scan file given; the synthetic after-scan needs ~synthetic";
      return false;
    }
    // rescan.reference mask: the mask cloud (~rescan_mask_file, in the before-scan's frame).
    std::optional<Cloud> mask;
    if (config.rescan.reference == shotcrete::ReferenceArea::mask) {
      if (rescan_mask_file_.empty()) {
        status = "rescan.reference is mask but ~rescan_mask_file is not set";
        return false;
      }
      try {
        mask = shotcrete::read_cloud(rescan_mask_file_);
      } catch (const std::exception& e) {
        status = std::string("mask cloud: ") + e.what();  // read_cloud names the file
        return false;
      }
      if (!origin.isZero(0.0)) mask->xyz.rowwise() -= (origin / config.io.unit_scale).transpose();
    }
    shotcrete::RescanOutcome out;
    std::optional<shotcrete::JobSummary> correction;
    try {
      double last_report = -1.0;
      out = shotcrete::rescan_job(surface->grid, *job->deposit_m, *job->before, after, config, mask ? &*mask : nullptr,
                                  initial_pose_, robot_.get(),
                                  [&](const std::string& stage, double fraction) {
                                    const double t = seconds_since(t0);
                                    if (t - last_report >= 2.0) {
                                      ROS_INFO("rescan: %s %.0f %%", stage.c_str(), 100.0 * fraction);
                                      last_report = t;
                                    }
                                  });
      if (out.correction)
        correction = shotcrete::summarise_job(*out.correction_surface, *out.correction, *robot_, *out.correction_config,
                                              {static_cast<long>(out.correction_surface->cloud.size())});
    } catch (const std::exception& e) {
      status = std::string("rescan of ") + source + " failed: " + e.what();
      return false;
    }
    const auto& grid = surface->grid;
    const auto& th = out.thickness;
    const auto& reg = out.registration;
    // ~thickness: one point per measured cell, on the wall as sprayed (before - layer along its ray).
    std::vector<int> cells;
    for (int c = 0; c < grid.size(); ++c)
      if (grid.valid[c] && std::isfinite(th.thickness_m[c]) && std::isfinite(th.before_td_m[c])) cells.push_back(c);
    shotcrete::Points xyz(static_cast<Eigen::Index>(cells.size()), 3);
    Eigen::VectorXd layer(xyz.rows()), lod(xyz.rows());
    for (std::size_t i = 0; i < cells.size(); ++i) {
      const int c = cells[i];
      const double r = grid.profile.radius_m + th.before_td_m[c] - th.thickness_m[c];
      xyz.row(static_cast<Eigen::Index>(i)) =
          grid.axis.to_cartesian(r, grid.theta_center(grid.row_of(c)), grid.d_center(grid.col_of(c))).transpose();
      layer[static_cast<Eigen::Index>(i)] = th.thickness_m[c];
      lod[static_cast<Eigen::Index>(i)] = th.lod95_m[c];
    }
    const double color_max = layer.size() ? std::max(1e-3, layer.maxCoeff()) : 1.0;
    thickness_pub_.publish(cells_to_msg(xyz, layer, lod, cells, color_max, frame_id_, ros::Time::now()));
    if (out.correction) publish_passes(*out.correction_surface, out.correction->plan, corrective_pub_);
    else clear_passes(corrective_pub_);
    clear_passes(passes_pub_);  // the executed plan is done: what is left to spray is the corrective round

    const Eigen::Matrix3d R = reg.transform.topLeftCorner<3, 3>();
    const double angle_deg = std::atan2(Eigen::Vector3d(R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1)).norm() / 2,
                                        (R.trace() - 1) / 2) * 180.0 / M_PI;
    const Eigen::Vector3d t = reg.transform.topRightCorner<3, 1>();
    std::string matrix = "[";
    for (int i = 0; i < 4; ++i) {
      matrix += i ? ", [" : "[";
      for (int j = 0; j < 4; ++j) matrix += (j ? ", " : "") + num(reg.transform(i, j), 9);
      matrix += "]";
    }
    matrix += "]";
    std::ostringstream js;
    js << "{\"ok\": true, \"source\": " << json_string(source) << ", \"registration\": {\"reference\": "
       << json_string(std::string(shotcrete::enum_name(config_.rescan.reference))) << ", \"rms_mm\": " << num(reg.rms_m * 1000)
       << ", \"overlap\": " << num(reg.overlap, 4) << ", \"iterations\": " << reg.iterations
       << ", \"matrix\": " << matrix << ", \"rotation_deg\": " << num(angle_deg, 4) << ", \"translation_m\": [" << num(t.x(), 4) << ", "
       << num(t.y(), 4) << ", " << num(t.z(), 4) << "], \"target_points\": " << reg.target_points
       << ", \"source_points\": " << reg.source_points << "}, \"before_td_rms_mm\": " << num(out.before_td_rms_m * 1000)
       << ", \"cells\": " << grid.valid_count() << ", \"cells_measured\": " << th.measured
       << ", \"thickness_mm\": " << stats_mm(th.thickness_m) << ", \"lod95_mm\": " << stats_mm(th.lod95_m)
       << ", \"residual_td_mm\": " << stats_mm(th.residual_td_m) << ", \"measured_vs_predicted_mm\": {\"bias\": "
       << num(out.comparison.bias_m * 1000) << ", \"rms\": " << num(out.comparison.rms_m * 1000)
       << ", \"max_abs\": " << num(out.comparison.max_abs_m * 1000) << ", \"cells\": " << out.comparison.cells
       << "}, \"calibration\": ";
    if (out.calibration)
      js << "{\"flow_factor\": " << num(out.calibration->factor, 5) << ", \"std_error\": "
         << num(out.calibration->std_error, 5) << ", \"cells\": " << out.calibration->cells << ", \"rejected\": "
         << out.calibration->rejected << ", \"residual_rms_mm\": " << num(out.calibration->residual_rms_m * 1000)
         << ", \"deposition_peak_rate_mps\": " << num(out.calibrated->deposition.peak_rate_mps, 6) << "}";
    else
      js << "{\"error\": " << json_string(out.calibration_error) << "}";
    js << ", \"correction\": " << (correction ? correction->to_json() : "null") << ", \"timings_s\": {\"register\": "
       << num(out.register_s) << ", \"measure\": " << num(out.measure_s) << ", \"correction\": "
       << num(out.correction_s) << ", \"total\": " << num(seconds_since(t0)) << "}}";
    status = js.str();
    ROS_INFO("rescan of %s in %.1f s: registration rms %.1f mm overlap %.2f, %d of %d cells measured, layer mean %.1f mm, "
             "flow factor %s, corrective round: %s (status on %s)",
             source.c_str(), seconds_since(t0), reg.rms_m * 1000, reg.overlap, th.measured, grid.valid_count(),
             th.thickness_m.unaryExpr([](double v) { return std::isfinite(v) ? v : 0.0; }).sum() * 1000 /
                 std::max(1, th.measured),
             out.calibration ? num(out.calibration->factor, 4).c_str() : out.calibration_error.c_str(),
             correction ? (std::to_string(correction->rounds) + " rounds, " + std::to_string(correction->passes) + " passes").c_str()
                        : "none",
             rescan_status_pub_.getTopic().c_str());
    if (correction) adopt_correction(std::move(out), *correction, after, source);
    return true;
  }

  /// The rescan's corrective round becomes the node's job: its surface (the after-scan's wall),
  /// plan, trajectory and executed deposit, the calibrated config, and the registered after-scan as
  /// the before-scan of a rescan after it; ~execute sprays it, ~summary shows it. A round that is not
  /// executable (its summary's problems) is shown, and ~execute refuses it as any plan.
  void adopt_correction(shotcrete::RescanOutcome&& out, const shotcrete::JobSummary& summary, const Cloud& after,
                        const std::string& source) {
    auto surface = std::make_shared<const Surface>(std::move(*out.correction_surface));
    const Cloud scaled = out.correction_config->io.unit_scale != 1.0
                             ? shotcrete::scale_cloud(after, out.correction_config->io.unit_scale)
                             : after;
    auto before = std::make_shared<const Cloud>(shotcrete::transform_cloud(scaled, out.registration.transform));
    auto plan = std::make_shared<const Plan>(std::move(out.correction->plan));
    std::shared_ptr<const shotcrete::TimedTrajectory> trajectory;
    std::shared_ptr<const shotcrete::ExecutedDeposit> executed;
    if (out.correction->trajectory)
      trajectory = std::make_shared<const shotcrete::TimedTrajectory>(std::move(*out.correction->trajectory));
    if (out.correction->executed)
      executed = std::make_shared<const shotcrete::ExecutedDeposit>(std::move(*out.correction->executed));
    const std::string problems = problems_text(summary);
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      surface_ = surface;
      before_scan_ = before;
      synthetic_bay_.reset();
      job_config_ = std::move(*out.correction_config);
      points_in_ = static_cast<long>(surface->cloud.size());
      plan_ = plan;
      plan_problems_ = problems;
      trajectory_ = trajectory;
      executed_ = executed;
      job_is_corrective_ = true;
    }
    const Eigen::VectorXd td = shotcrete::point_td(surface->cloud, surface->axis, surface->profile);
    publish_cloud(surface->cloud.xyz, td);
    publish_levels(*surface);
    std_msgs::String msg;
    msg.data = summary.to_json();
    summary_pub_.publish(msg);
    ROS_INFO("the corrective round of %s is the job now: %d rounds, %d passes, %s (call %s to spray it)", source.c_str(),
             summary.rounds, summary.passes, problems.empty() ? "executable" : ("not executable: " + problems).c_str(),
             pnh_.resolveName("execute").c_str());
  }

  /// Runs rescan and reports it: the status (or the error as {"ok": false, "error": ...}) on
  /// ~rescan_status and in the log.
  bool rescan_and_report(const Cloud* after, const std::string& source, std::string& message) {
    bool ok = false;
    try {
      ok = rescan(after, source, message);
    } catch (const std::exception& e) {
      message = std::string("rescan failed: ") + e.what();
    }
    std_msgs::String msg;
    msg.data = ok ? message : "{\"ok\": false, \"error\": " + json_string(message) + "}";
    rescan_status_pub_.publish(msg);
    if (!ok) ROS_WARN("rescan: %s", message.c_str());
    return ok;
  }

  /// ~rescan with a file (empty: the synthetic after-scan).
  bool rescan_file(const std::string& path, std::string& message) {
    if (path.empty()) return rescan_and_report(nullptr, "the synthetic after-scan", message);
    Cloud after;
    try {
      after = shotcrete::read_cloud(path);
    } catch (const std::exception& e) {
      message = std::string("after-scan: ") + e.what();  // read_cloud names the file
      std_msgs::String msg;
      msg.data = "{\"ok\": false, \"error\": " + json_string(message) + "}";
      rescan_status_pub_.publish(msg);
      ROS_WARN("rescan: %s", message.c_str());
      return false;
    }
    return rescan_and_report(&after, path, message);
  }

 private:
  // ---------------------------------------------------------------------------------------------
  // Input
  // ---------------------------------------------------------------------------------------------
  void on_cloud(const sensor_msgs::PointCloud2::ConstPtr& msg) {
    auto cloud = std::make_shared<Cloud>();
    const std::string reason = cloud_from_msg(*msg, frame_id_, *cloud, static_cast<std::size_t>(max_points_));
    if (!reason.empty()) {
      ROS_WARN("cloud on %s ignored: %s", cloud_sub_.getTopic().c_str(), reason.c_str());
      return;
    }
    std::unique_lock<std::mutex> work(work_mutex_, std::try_to_lock);
    if (!work.owns_lock()) {
      ROS_WARN("cloud on %s ignored: busy planning or executing", cloud_sub_.getTopic().c_str());
      return;
    }
    std::string error;
    if (!set_cloud(cloud, "topic " + cloud_sub_.getTopic(), error))
      ROS_WARN("cloud on %s ignored: %s", cloud_sub_.getTopic().c_str(), error.c_str());
  }

  void on_after_scan(const sensor_msgs::PointCloud2::ConstPtr& msg) {
    Cloud cloud;
    std::string message = cloud_from_msg(*msg, frame_id_, cloud, static_cast<std::size_t>(max_points_));
    if (!message.empty()) {
      message = "after-scan on " + after_sub_.getTopic() + " ignored: " + message;
      std_msgs::String status;
      status.data = "{\"ok\": false, \"error\": " + json_string(message) + "}";
      rescan_status_pub_.publish(status);
      ROS_WARN("rescan: %s", message.c_str());
      return;
    }
    rescan_and_report(&cloud, "topic " + after_sub_.getTopic(), message);
  }

  /// `before_scan`: what a re-scan registers to (the scan with its surroundings); default `cloud`
  /// itself (kept, not copied, unless survey coordinates move it into a local frame). The caller
  /// holds work_mutex_.
  bool set_cloud(std::shared_ptr<const Cloud> cloud, const std::string& source, std::string& error,
                 std::shared_ptr<const Cloud> before_scan = nullptr) {
    const auto t0 = Clock::now();
    auto surface = std::make_shared<Surface>();
    shotcrete::Config config;
    Eigen::Vector3d origin = Eigen::Vector3d::Zero();
    std::unique_ptr<shotcrete::Robot> moved_robot;
    try {
      // profile.alignment_path: the axis from the alignment where this scan lies (in metres, in
      // double precision, before the shift).
      shotcrete::AxisOnAlignment at;
      const double scale = config_.io.unit_scale;
      config = config_.profile.alignment_path.empty() || scale == 1.0
                   ? shotcrete::with_alignment_axis(config_, cloud->xyz, &at)
                   : shotcrete::with_alignment_axis(config_, shotcrete::Points(cloud->xyz * scale), &at);
      if (!config_.profile.alignment_path.empty())
        ROS_INFO("axis from the alignment at chainage %.3f m (straight over %.3f..%.3f m, deviation %.4f m)",
                 at.chainage_m, at.start_m, at.end_m, at.deviation_m);
      // Survey coordinates: the cloud and the config's coordinates move into a local frame before
      // any float32 stage, as the CLI does (the same core functions).
      origin = shotcrete::local_frame_origin(cloud->xyz, config.io);
      if (!origin.isZero(0.0)) {
        auto local = std::make_shared<Cloud>(*cloud);
        shotcrete::to_local_frame(origin, *local, config);
        cloud = local;
        if (before_scan) {  // in the input's frame too
          auto b = std::make_shared<Cloud>(*before_scan);
          b->xyz.rowwise() -= (origin / config.io.unit_scale).transpose();
          before_scan = b;
        }
      }
      if (config.robot.base_position_m != robot_->base_pose().translation())
        moved_robot = std::make_unique<shotcrete::Robot>(shotcrete::Robot::load_file(urdf_path_, config.robot.base_position_m));
      *surface = shotcrete::build_surface(*cloud, config);
    } catch (const std::exception& e) {
      error = e.what();
      return false;
    }
    if (moved_robot) robot_ = std::move(moved_robot);  // no plan, execution or rescan runs (work_mutex_)
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      surface_ = surface;
      local_origin_m_ = origin;
      job_config_ = config;
      before_scan_ = before_scan ? before_scan : cloud;
      synthetic_bay_.reset();
      sprayed_.reset();
      job_is_corrective_ = false;
      points_in_ = static_cast<long>(cloud->size());
      plan_.reset();
      plan_problems_.clear();
      trajectory_.reset();
    }
    pnh_.setParam("local_origin_m", std::vector<double>{origin.x(), origin.y(), origin.z()});
    publish_base_transform();
    if (!origin.isZero(0.0))
      ROS_INFO("cloud in survey coordinates: planned in a local frame, %s = %s + (%.3f, %.3f, %.3f) m (~local_origin_m, tf_static)",
               survey_frame_id_.c_str(), frame_id_.c_str(), origin.x(), origin.y(), origin.z());
    const Eigen::VectorXd td = shotcrete::point_td(surface->cloud, surface->axis, surface->profile);
    color_max_m_ = td_color_max_m_ > 0 ? td_color_max_m_ : std::max(1e-3, td.maxCoeff());
    publish_cloud(surface->cloud.xyz, td);
    publish_levels(*surface);
    clear_passes(passes_pub_);
    clear_passes(corrective_pub_);
    thickness_pub_.publish(cells_to_msg(shotcrete::Points(0, 3), Eigen::VectorXd(0), Eigen::VectorXd(0), {}, 1.0,
                                        frame_id_, ros::Time::now()));
    ROS_INFO("cloud from %s: %ld points in, %ld kept, %d grid cells (%d valid), levels %s, %.2f s", source.c_str(),
             static_cast<long>(cloud->size()), static_cast<long>(surface->cloud.size()), surface->grid.size(),
             surface->grid.valid_count(), levels_text(shotcrete::level_counts(surface->levels)).c_str(),
             seconds_since(t0));
    return true;
  }

  // ---------------------------------------------------------------------------------------------
  // Services
  // ---------------------------------------------------------------------------------------------
  bool on_plan(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    try {
      res.success = plan(res.message);
    } catch (const std::exception& e) {
      res.success = false;
      res.message = std::string("plan failed: ") + e.what();
    }
    if (!res.success) ROS_WARN("plan: %s", res.message.c_str());  // plan() logs a success itself
    return true;
  }

  bool on_rescan(shotcrete_ros::Rescan::Request& req, shotcrete_ros::Rescan::Response& res) {
    res.success = rescan_file(req.path, res.message);
    return true;
  }

  bool on_execute(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    try {
      res.success = execute(res.message);
    } catch (const std::exception& e) {
      res.success = false;
      res.message = std::string("execute failed: ") + e.what();
    }
    if (res.success)
      ROS_INFO("execute: %s", res.message.c_str());
    else
      ROS_WARN("execute: %s", res.message.c_str());
    return true;
  }

  // ---------------------------------------------------------------------------------------------
  // Execution helpers
  // ---------------------------------------------------------------------------------------------
  shotcrete::SpotModel spot_model() const {
    return shotcrete::spot_model_from_config(config_.deposition);
  }

  void deposit(const shotcrete::SpotModel& model, const shotcrete::SurfaceIndex& index,
               const shotcrete::TimedTrajectory& traj, const std::vector<double>& dwell, std::size_t from,
               std::size_t to, Eigen::VectorXd& deposited) const {
    std::vector<shotcrete::NozzlePose> poses;
    std::vector<double> dwells;
    for (std::size_t i = from; i < to && i < traj.size(); ++i) {
      if (dwell[i] <= 0) continue;
      poses.push_back(traj.nozzle[i]);
      dwells.push_back(dwell[i]);
    }
    if (!poses.empty())
      shotcrete::accumulate_dwells(model, index, poses, dwells, config_.deposition.rebound_fraction, deposited);
  }

  /// Joints at time t, linear between the samples k - 1 and k (t_s[k] >= t).
  static Eigen::VectorXd interpolate(const shotcrete::TimedTrajectory& traj, double t, std::size_t k) {
    if (k == 0) return traj.q.front();
    const double t0 = traj.t_s[k - 1], t1 = traj.t_s[k];
    const double u = t1 > t0 ? std::clamp((t - t0) / (t1 - t0), 0.0, 1.0) : 1.0;
    return (1.0 - u) * traj.q[k - 1] + u * traj.q[k];
  }

  // ---------------------------------------------------------------------------------------------
  // Publishing
  // ---------------------------------------------------------------------------------------------
  void publish_joints(const Eigen::VectorXd& q, const ros::Time& stamp) {
    sensor_msgs::JointState js;
    js.header.stamp = stamp;
    js.name = joint_names_;
    js.position.assign(q.data(), q.data() + q.size());
    joint_pub_.publish(js);
  }

  /// tf_static: frame_id -> base_link (the arm's base in the local frame) and survey_frame_id ->
  /// frame_id (the local origin; identity for a cloud near its own origin), in one latched message.
  void publish_base_transform() {
    auto transform = [&](const std::string& parent, const std::string& child, const Eigen::Vector3d& p) {
      geometry_msgs::TransformStamped tf;
      tf.header.stamp = ros::Time::now();
      tf.header.frame_id = parent;
      tf.child_frame_id = child;
      tf.transform.translation.x = p.x();
      tf.transform.translation.y = p.y();
      tf.transform.translation.z = p.z();
      tf.transform.rotation.w = 1.0;
      return tf;
    };
    Eigen::Vector3d origin;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      origin = local_origin_m_;
    }
    tf2_msgs::TFMessage msg;
    msg.transforms.push_back(transform(frame_id_, "base_link", robot_->base_pose().translation()));
    msg.transforms.push_back(transform(survey_frame_id_, frame_id_, origin));
    tf_static_pub_.publish(msg);
  }

  void publish_cloud(const shotcrete::Points& xyz, const Eigen::VectorXd& td) {
    cloud_pub_.publish(cloud_to_msg(xyz, td, color_max_m_, frame_id_, ros::Time::now()));
  }

  visualization_msgs::Marker marker(const std::string& ns, int id, int type) const {
    visualization_msgs::Marker m;
    m.header.frame_id = frame_id_;
    m.header.stamp = ros::Time::now();
    m.ns = ns;
    m.id = id;
    m.type = type;
    m.action = visualization_msgs::Marker::ADD;
    m.pose.orientation.w = 1.0;
    return m;
  }

  static visualization_msgs::Marker delete_all() {
    visualization_msgs::Marker m;
    m.action = 3;  // DELETEALL
    return m;
  }

  /// One cube list per level on the design line (where the wall should end up).
  void publish_levels(const Surface& surface) {
    visualization_msgs::MarkerArray arr;
    arr.markers.push_back(delete_all());
    const auto& grid = surface.grid;
    std::map<int, std::vector<int>> by_level;
    for (int c = 0; c < grid.size(); ++c)
      if (surface.levels[c] != shotcrete::kNoDataLevel) by_level[surface.levels[c]].push_back(c);
    int max_level = 1;
    for (const auto& [level, cells] : by_level) max_level = std::max(max_level, level);
    for (const auto& [level, cells] : by_level) {
      auto m = marker("levels", level - shotcrete::kNoDataLevel, visualization_msgs::Marker::CUBE_LIST);
      m.scale.x = m.scale.y = m.scale.z = 0.9 * grid.cell_size_m;
      m.color = level <= 0 ? std_msgs::ColorRGBA() : colormap(static_cast<double>(level) / max_level, 0.8f);
      if (level <= 0) m.color.r = m.color.g = m.color.b = 0.5f, m.color.a = 0.8f;
      for (int c : cells) m.points.push_back(point_msg(grid.design_point(c)));
      arr.markers.push_back(m);
    }
    levels_pub_.publish(arr);
  }

  static void clear_passes(ros::Publisher& pub) {
    visualization_msgs::MarkerArray arr;
    arr.markers.push_back(delete_all());
    pub.publish(arr);
  }

  /// Passes (line list coloured by speed), region outlines on the design line, transit links.
  void publish_passes(const Surface& surface, const Plan& plan, ros::Publisher& pub) {
    visualization_msgs::MarkerArray arr;
    arr.markers.push_back(delete_all());
    const auto& grid = plan.grid_before.size() > 0 ? plan.grid_before : surface.grid;
    const double vmin = config_.planner.min_speed_mps, vmax = config_.planner.max_speed_mps;
    for (std::size_t r = 0; r < plan.rounds.size(); ++r) {
      const auto& round = plan.rounds[r];
      auto passes = marker("passes", static_cast<int>(r), visualization_msgs::Marker::LINE_LIST);
      passes.scale.x = 0.012;
      auto boxes = marker("regions", static_cast<int>(r), visualization_msgs::Marker::LINE_LIST);
      boxes.scale.x = 0.008;
      boxes.color.r = 1.0f, boxes.color.g = 1.0f, boxes.color.b = 1.0f, boxes.color.a = 0.9f;
      auto links = marker("transits", static_cast<int>(r), visualization_msgs::Marker::LINE_LIST);
      links.scale.x = 0.006;
      links.color.r = 0.8f, links.color.g = 0.3f, links.color.b = 0.9f, links.color.a = 0.9f;
      bool have_prev = false;
      Eigen::Vector3d prev_end = Eigen::Vector3d::Zero();
      for (const auto& region : round.regions) {
        const auto& ordered = region.passes;  // in spraying order (reversed regions already flipped)
        for (const auto& pass : ordered) {
          const auto c = colormap(vmax > vmin ? (pass.speed_mps - vmin) / (vmax - vmin) : 0.5);
          for (std::size_t i = 1; i < pass.waypoints.size(); ++i) {
            passes.points.push_back(point_msg(pass.waypoints[i - 1].position_m));
            passes.points.push_back(point_msg(pass.waypoints[i].position_m));
            passes.colors.push_back(c);
            passes.colors.push_back(c);
          }
        }
        if (!ordered.empty() && !ordered.front().waypoints.empty()) {
          if (have_prev) {
            links.points.push_back(point_msg(prev_end));
            links.points.push_back(point_msg(ordered.front().waypoints.front().position_m));
          }
          prev_end = ordered.back().waypoints.back().position_m;
          have_prev = true;
        }
        add_region_outline(grid, region.region, boxes);
      }
      for (auto* m : {&passes, &boxes, &links})
        if (!m->points.empty()) arr.markers.push_back(*m);
    }
    pub.publish(arr);
  }

  /// Per link with collision geometry: its shapes at the trajectory sample of its least distance to
  /// the wall (ns "clearance_links", red when closer than its margin, green otherwise), a sphere at
  /// the wall's closest point then (ns "clearance_closest") and a label with the distance
  /// (ns "clearance_text").
  void publish_clearance(const shotcrete::ClearanceReport& rep, const shotcrete::TimedTrajectory& traj) {
    visualization_msgs::MarkerArray arr;
    arr.markers.push_back(delete_all());
    if (traj.size() == 0) return clearance_pub_.publish(arr);
    const auto& shapes = robot_->collision_shapes();
    int id = 0;
    for (std::size_t l = 0; l < rep.links.size(); ++l) {
      const auto& lc = rep.links[l];
      if (!std::isfinite(lc.min_m)) continue;
      const bool below = lc.min_m < lc.margin_m;
      std_msgs::ColorRGBA color;
      color.r = below ? 1.0f : 0.1f, color.g = below ? 0.1f : 0.8f, color.b = 0.1f, color.a = below ? 0.9f : 0.5f;
      const auto k = static_cast<std::size_t>(
          std::lower_bound(traj.t_s.begin(), traj.t_s.end(), lc.at_time_s) - traj.t_s.begin());
      const auto frames = robot_->link_frames(traj.q[std::min(k, traj.size() - 1)]);
      for (const auto& s : shapes) {
        if (s.link != lc.link) continue;
        using M = visualization_msgs::Marker;
        auto m = marker("clearance_links", id++,
                        s.kind == shotcrete::CollisionShape::Kind::cylinder ? M::CYLINDER
                        : s.kind == shotcrete::CollisionShape::Kind::box   ? M::CUBE
                                                                           : M::SPHERE);
        const Eigen::Isometry3d T = frames[s.frame] * s.origin;
        const Eigen::Quaterniond q(T.linear());
        m.pose.position = point_msg(T.translation());
        m.pose.orientation.x = q.x(), m.pose.orientation.y = q.y(), m.pose.orientation.z = q.z(), m.pose.orientation.w = q.w();
        if (s.kind == shotcrete::CollisionShape::Kind::cylinder)
          m.scale.x = m.scale.y = 2.0 * s.radius_m, m.scale.z = s.length_m;
        else if (s.kind == shotcrete::CollisionShape::Kind::box)
          m.scale.x = s.size_m.x(), m.scale.y = s.size_m.y(), m.scale.z = s.size_m.z();
        else
          m.scale.x = m.scale.y = m.scale.z = 2.0 * s.radius_m;
        m.color = color;
        arr.markers.push_back(m);
      }
      auto dot = marker("clearance_closest", static_cast<int>(l), visualization_msgs::Marker::SPHERE);
      dot.pose.position = point_msg(lc.closest_m);
      dot.scale.x = dot.scale.y = dot.scale.z = 0.08;
      dot.color = color, dot.color.a = 1.0f;
      arr.markers.push_back(dot);
      auto text = marker("clearance_text", static_cast<int>(l), visualization_msgs::Marker::TEXT_VIEW_FACING);
      text.pose.position = point_msg(lc.closest_m + Eigen::Vector3d(0, 0, -0.15));
      text.scale.z = 0.1;
      text.color = dot.color;
      std::ostringstream t;
      t << std::fixed << std::setprecision(2) << lc.link << " " << lc.min_m << " m (margin " << lc.margin_m << ") at "
        << std::setprecision(0) << lc.at_time_s << " s";
      text.text = t.str();
      arr.markers.push_back(text);
    }
    clearance_pub_.publish(arr);
  }

  /// Outline of a region's bounding box of cells, drawn on the design line (arcs along theta).
  static void add_region_outline(const shotcrete::Grid& grid, const shotcrete::Region& region,
                                 visualization_msgs::Marker& m) {
    const double th0 = grid.theta0_rad + region.row_min * grid.dtheta_rad;
    const double th1 = grid.theta0_rad + (region.row_max + 1) * grid.dtheta_rad;
    const double d0 = grid.d0_m + region.col_min * grid.cell_size_m;
    const double d1 = grid.d0_m + (region.col_max + 1) * grid.cell_size_m;
    const double r = grid.profile.radius_m;
    auto at = [&](double th, double d) { return point_msg(grid.axis.to_cartesian(r, th, d)); };
    const int steps = std::max(1, static_cast<int>(std::ceil((th1 - th0) * r / 0.1)));
    for (int i = 0; i < steps; ++i) {
      const double a = th0 + (th1 - th0) * i / steps, b = th0 + (th1 - th0) * (i + 1) / steps;
      for (double d : {d0, d1}) {
        m.points.push_back(at(a, d));
        m.points.push_back(at(b, d));
      }
    }
    for (double th : {th0, th1}) {
      m.points.push_back(at(th, d0));
      m.points.push_back(at(th, d1));
    }
  }

  ros::NodeHandle nh_, pnh_;
  Config config_;
  std::string config_path_, frame_id_, urdf_path_;
  double time_scale_ = 1.0, max_wall_s_ = 0.0, joint_rate_hz_ = 50.0, cloud_rate_hz_ = 2.0, td_color_max_m_ = 0.0;
  double color_max_m_ = 0.3;
  int max_points_ = 20000000;
  std::string survey_frame_id_;
  std::unique_ptr<shotcrete::Robot> robot_;  // replaced (under work_mutex_) when a cloud's local frame or a plan's place_base moves its base
  std::vector<std::string> joint_names_;     // robot_'s, for the idle timer (which takes no lock)
  Eigen::VectorXd q_current_;
  std::atomic<bool> executing_{false};

  std::mutex work_mutex_;   // one plan / execution / cloud update at a time
  std::mutex state_mutex_;  // guards the snapshots below
  std::shared_ptr<const Surface> surface_;
  // The cloud's local frame (shotcrete/io/survey.hpp): survey coordinates = local + origin. Every
  // cloud, marker and pose the node publishes is local; job_config_ is config_ moved into it.
  Eigen::Vector3d local_origin_m_ = Eigen::Vector3d::Zero();
  Config job_config_;
  long points_in_ = 0;  // points of the cloud surface_ was built from
  std::shared_ptr<const Plan> plan_;
  std::string plan_problems_;  // of plan_ (JobSummary problems); ~execute refuses while not empty
  std::shared_ptr<const shotcrete::TimedTrajectory> trajectory_;
  std::shared_ptr<const shotcrete::ExecutedDeposit> executed_;  // of trajectory_
  std::shared_ptr<const Cloud> before_scan_;  // what a rescan of surface_'s job registers to (the input, the
                                              // synthetic scan, or the registered after-scan of a corrective round)
  std::shared_ptr<const shotcrete::SyntheticBay> synthetic_bay_;  // with ~synthetic: the after-scan's generator
  // What ~rescan measures: the job ~execute ran last (its surface, before-scan, config and executed
  // deposit per grid cell). A rescan makes its corrective round the node's job (surface_, plan_, ...),
  // so ~execute sprays it; until then further rescans still measure the job sprayed before.
  struct SprayedJob {
    std::shared_ptr<const Surface> surface;
    std::shared_ptr<const Cloud> before;
    std::shared_ptr<const shotcrete::SyntheticBay> bay;  // null: no synthetic after-scan (a corrective round)
    Config config;
    std::shared_ptr<const Eigen::VectorXd> deposit_m;
    bool corrective = false;  // a rescan's corrective round
  };
  std::shared_ptr<const SprayedJob> sprayed_;
  bool job_is_corrective_ = false;  // surface_'s job is a rescan's corrective round
  std::string rescan_mask_file_;  // ~rescan_mask_file: the mask cloud of rescan.reference mask
  Eigen::Matrix4d initial_pose_ = Eigen::Matrix4d::Identity();  // ~rescan_initial_pose: after -> before start

  ros::Publisher cloud_pub_, levels_pub_, passes_pub_, clearance_pub_, summary_pub_, joint_pub_, tf_static_pub_;
  ros::Publisher thickness_pub_, corrective_pub_, rescan_status_pub_;
  ros::Subscriber cloud_sub_, after_sub_;
  ros::ServiceServer plan_srv_, execute_srv_, rescan_srv_;
  ros::WallTimer idle_timer_;
};

}  // namespace shotcrete_ros

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // log lines appear at once when stdout is a file
  ros::init(argc, argv, "shotcrete_node");
  ros::NodeHandle nh, pnh("~");
  std::unique_ptr<shotcrete_ros::ShotcreteNode> node;
  try {
    node = std::make_unique<shotcrete_ros::ShotcreteNode>(nh, pnh);
  } catch (const std::exception& e) {
    ROS_FATAL("shotcrete_node cannot start: %s", e.what());
    return 1;
  }
  ros::AsyncSpinner spinner(3);  // services block while planning / executing; topics keep flowing
  spinner.start();
  bool auto_plan = false, auto_execute = false, auto_rescan = false, auto_correct = false;
  std::string after_scan_file;
  pnh.param("auto_plan", auto_plan, false);
  pnh.param("auto_execute", auto_execute, false);
  pnh.param("auto_rescan", auto_rescan, false);          // after auto_execute: ~rescan of ~after_scan_file
  pnh.param("auto_correct", auto_correct, false);        // after auto_rescan: ~execute of its corrective round
  pnh.param<std::string>("after_scan_file", after_scan_file, "");  // empty: the synthetic after-scan
  try {
    const bool have_cloud = node->load_initial_cloud();
    if (have_cloud && auto_plan) {
      std::string summary;
      if (node->plan(summary)) {
        if (auto_execute) {
          if (node->execute(summary)) {
            ROS_INFO("execute: %s", summary.c_str());
            if (auto_rescan && node->rescan_file(after_scan_file, summary) && auto_correct) {
              if (node->execute(summary))
                ROS_INFO("execute (corrective round): %s", summary.c_str());
              else
                ROS_WARN("execute (corrective round): %s", summary.c_str());
            }
          } else {
            ROS_WARN("execute: %s", summary.c_str());
          }
        }
      } else {
        ROS_ERROR("plan: %s", summary.c_str());
      }
    }
  } catch (const std::exception& e) {
    ROS_FATAL("shotcrete_node: %s", e.what());
    return 1;
  }
  ros::waitForShutdown();
  return 0;
}
