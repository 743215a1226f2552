// Bay planning for a given arm: caps, plan, time, learn, re-plan (see arm_plan.hpp).
#include "shotcrete/arm_plan.hpp"

#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <memory>

#include "shotcrete/robot.hpp"

namespace shotcrete {

double SpeedCapMap::at(const Eigen::Vector3d& p) const {
  double best = std::numeric_limits<double>::infinity();
  const double r2 = radius_m * radius_m;
  for (std::size_t i = 0; i < points_m.size(); ++i)
    if (speed_mps[i] < best && (points_m[i] - p).squaredNorm() <= r2) best = speed_mps[i];
  return best;
}

int SpeedCapMap::learn(const TimedTrajectory& tr, const Eigen::VectorXd& vel_limit, const Eigen::VectorXd& acc_limit,
                       double limit_share) {
  int added = 0;
  for (std::size_t i = 1; i + 1 < tr.size(); ++i) {
    const auto kind = static_cast<SegmentKind>(tr.kind[i]);
    const bool pass = kind == SegmentKind::Pass || tr.spraying[i];
    if (!pass && kind != SegmentKind::Link && kind != SegmentKind::Lead) continue;
    const double rv = tr.qd[i].cwiseAbs().cwiseQuotient(vel_limit).maxCoeff();
    const double ra = tr.qdd[i].cwiseAbs().cwiseQuotient(acc_limit).maxCoeff();
    if (!(rv > 1.0 || (pass && ra > 1.0))) continue;
    const double dt = tr.t_s[i + 1] - tr.t_s[i - 1];
    if (!(dt > 0.0)) continue;
    const double v = (tr.nozzle[i + 1].position_m - tr.nozzle[i - 1].position_m).norm() / dt;
    double factor = limit_share / std::max(rv, 1e-12);
    if (pass) factor = std::min(factor, std::sqrt(limit_share / std::max(ra, 1e-12)));
    if (!(v > 0.0) || factor >= 1.0) continue;
    points_m.push_back(tr.nozzle[i].position_m);
    speed_mps.push_back(v * factor);
    ++added;
  }
  return added;
}

ArmPlan plan_for_arm(const Surface& surface, const Config& config, const Robot& robot, const ProgressFn& progress) {
  ArmPlan out;
  // The arm's caps depend on a pass's geometry only: the lines of a round repeat across re-plans,
  // so they are computed once (keyed by their size and end points).
  using Key = std::array<double, 7>;
  auto cache = std::make_shared<std::map<Key, std::vector<double>>>();
  const SpeedCapFn arm = arm_speed_caps(robot, config);
  const SpeedCapFn cap = [&, cache](const std::vector<NozzlePose>& wp) {
    if (wp.empty()) return std::vector<double>{};
    const Eigen::Vector3d a = wp.front().position_m, b = wp.back().position_m;
    const Key key{static_cast<double>(wp.size()), a.x(), a.y(), a.z(), b.x(), b.y(), b.z()};
    auto it = cache->find(key);
    if (it == cache->end()) it = cache->emplace(key, arm(wp)).first;
    std::vector<double> c = it->second;
    if (!out.learned.points_m.empty())
      for (std::size_t k = 0; k < wp.size(); ++k) c[k] = std::min(c[k], out.learned.at(wp[k].position_m));
    return c;
  };
  const double share = 1.0 - config.timing.joint_limit_margin;
  for (int attempt = 0;; ++attempt) {
    const std::string prefix = attempt == 0 ? "" : "re-plan " + std::to_string(attempt) + ": ";
    out.plan = plan_bay(surface, config, progress ? ProgressFn([&](const std::string& s, double f) { progress(prefix + s, f); }) : ProgressFn{}, cap);
    out.replans = attempt;
    if (progress) progress(prefix + "trajectory", 0.0);
    std::vector<std::vector<Pass>> regions;
    for (const auto& round : out.plan.rounds)
      for (const auto& region : round.regions) regions.push_back(region.passes);  // in spraying order
    out.trajectory.reset();
    out.timing_error.clear();
    if (regions.empty()) break;
    try {
      out.trajectory = time_plan(robot, regions, robot.neutral(), config.timing, config.robot);
    } catch (const std::exception& e) {
      out.timing_error = e.what();
      break;
    }
    if (progress) progress(prefix + "trajectory", 1.0);
    if (attempt >= config.timing.max_replans) break;
    if (out.learned.learn(*out.trajectory, robot.velocity_limits(), robot.acceleration_limits(), share) == 0) break;
  }
  return out;
}

}  // namespace shotcrete
