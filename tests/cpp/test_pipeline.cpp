// Pipeline: the JSON writer and the job summary (summarise_job) of a bay planned for the arm.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "shotcrete/io/json_writer.hpp"
#include "shotcrete/pipeline/arm_plan.hpp"
#include "shotcrete/pipeline/job_summary.hpp"
#include "shotcrete/robot/robot.hpp"
#include "bay_fixtures.hpp"

using namespace shotcrete;

namespace {

std::string number(double v) {
  JsonWriter w;
  w.value(v);
  return w.str();
}

// A slice of the wall with one dig pit (radius 0.4 m) in a uniform over-break.
Surface pit_bay(Config& cfg, double pit_depth_m = 0.15, double overbreak_m = 0.04) {
  const double R = cfg.profile.design_radius_m;
  auto td = [=](double d, double theta) {
    const double q = (std::pow(d - 0.3, 2) + std::pow((theta - 1.4) * R, 2)) / (0.4 * 0.4);
    return overbreak_m + (q < 1 ? pit_depth_m * std::pow(1 - q, 1.5) : 0.0);
  };
  return test::analytic_bay(td, cfg, 1.2, 1.6, 0.6, 3);
}

}  // namespace

TEST(JsonWriter, NumbersReadBackAsTheSameDoubles) {
  EXPECT_EQ(number(0.1), "0.10000000000000001");
  EXPECT_EQ(number(1.0), "1.0");  // a float stays a float
  EXPECT_EQ(number(-0.0), "-0.0");
  EXPECT_EQ(number(1e20), "1e+20");
  EXPECT_EQ(number(std::numeric_limits<double>::quiet_NaN()), "null");
  EXPECT_EQ(number(std::numeric_limits<double>::infinity()), "Infinity");
  EXPECT_EQ(number(-std::numeric_limits<double>::infinity()), "-Infinity");
  for (const double v : {1.0 / 3.0, 5405.123456789012, 2.5e-300, -7.75e-9})
    EXPECT_EQ(std::strtod(number(v).c_str(), nullptr), v) << number(v);
}

TEST(JsonWriter, NestingKeysAndEscapes) {
  JsonWriter w;
  w.begin_object().field("a", 1).field("b", true).key("list").begin_array().value(2).value("x").null();
  w.begin_object().end_object().end_array().field("text", std::string("q\"b\\n\nt\t\x01")).end_object();
  EXPECT_EQ(w.str(), R"({"a":1,"b":true,"list":[2,"x",null,{}],"text":"q\"b\\n\nt\t\u0001"})");
  EXPECT_EQ(json_quote("Grün"), "\"Grün\"");  // UTF-8 passes through
}

TEST(JsonWriter, MisuseIsAnError) {
  JsonWriter a;
  EXPECT_THROW(a.end_object(), std::logic_error);
  JsonWriter b;
  b.begin_object().key("k");
  EXPECT_THROW(b.key("again"), std::logic_error);
  EXPECT_THROW(b.end_object(), std::logic_error);
  JsonWriter c;
  c.value(1);
  EXPECT_THROW(c.value(2), std::logic_error);
}

TEST(JobSummary, FiguresOfABayPlannedForTheArm) {
  Config cfg;
  const Surface surface = pit_bay(cfg);
  const Robot robot = Robot::load(cfg.robot);
  const ArmPlan arm = plan_for_arm(surface, cfg, robot);
  ASSERT_TRUE(arm.trajectory) << arm.timing_error;
  const JobSummary s = summarise_job(surface, arm, robot, cfg, {1234, 10});
  const Plan& plan = arm.plan;

  EXPECT_EQ(s.mode, std::string(enum_name(cfg.planner.mode)));
  EXPECT_EQ(s.points_in, 1234);
  EXPECT_EQ(s.points_used, static_cast<long>(surface.cloud.size()));
  EXPECT_EQ(s.cells, surface.grid.valid_count());
  int passes = 0, regions = 0, poses = 0, after = 0;
  for (const auto& round : plan.rounds)
    for (const auto& region : round.regions) {
      ++regions;
      passes += static_cast<int>(region.passes.size());
      for (const auto& p : region.passes) poses += static_cast<int>(p.waypoints.size());
    }
  EXPECT_GT(passes, 0);
  EXPECT_EQ(s.passes, passes);
  EXPECT_EQ(s.regions, regions);
  EXPECT_EQ(s.rounds, static_cast<int>(plan.rounds.size()));
  ASSERT_EQ(s.rounds_detail.size(), plan.rounds.size());
  EXPECT_EQ(s.rounds_detail.front().round, 1);
  for (const auto& [level, n] : s.planned_levels_after) {
    EXPECT_LE(level, 0);
    after += n;
  }
  EXPECT_EQ(after, s.cells);
  after = 0;
  for (const auto& [level, n] : s.levels_after) after += n;
  EXPECT_EQ(after, s.cells);
  // Residual over the valid cells, in mm: the executed deposit's, and the planner's estimate.
  ASSERT_TRUE(arm.executed);
  EXPECT_EQ(s.deposit_source, "executed");
  const Eigen::VectorXd& executed_td = arm.executed->td_after_m;
  for (const auto* stats : {&s.residual_mm, &s.planned_residual_mm}) {
    const Eigen::VectorXd& td = stats == &s.residual_mm ? executed_td : plan.td_after_m;
    double lo = 1e9, hi = -1e9;
    for (std::size_t c = 0; c < surface.grid.valid.size(); ++c)
      if (surface.grid.valid[c]) {
        lo = std::min(lo, td[static_cast<Eigen::Index>(c)] * 1000.0);
        hi = std::max(hi, td[static_cast<Eigen::Index>(c)] * 1000.0);
      }
    EXPECT_DOUBLE_EQ(stats->min, lo);
    EXPECT_DOUBLE_EQ(stats->max, hi);
    EXPECT_DOUBLE_EQ(stats->abs_max, std::max(std::abs(lo), std::abs(hi)));
  }
  ASSERT_TRUE(s.planned_vs_executed_mm && s.executed);
  EXPECT_GE(s.planned_vs_executed_mm->rms, std::abs(s.planned_vs_executed_mm->mean));
  // The planner deposits along the timed Cartesian path with the pump's flow (region_spray): it
  // predicts what the arm executes to within 1 mm RMS (issue 15's target).
  EXPECT_LT(s.planned_vs_executed_mm->rms, 1.0);
  EXPECT_LT(std::abs(s.executed->balance_error), 0.01);
  EXPECT_GE(s.executed->shortest_on_s, cfg.flow.min_on_s - 1e-9);
  EXPECT_LE(s.residual_mm.min, s.residual_mm.mean);
  EXPECT_LE(s.residual_mm.mean, s.residual_mm.max);
  EXPECT_GE(s.residual_mm.rms, std::abs(s.residual_mm.mean));
  EXPECT_GT(s.td_before_mm.mean, 40.0);
  ASSERT_TRUE(s.spray_time_ratio);
  EXPECT_DOUBLE_EQ(*s.spray_time_ratio, plan.spray_time_s / plan.physical_limit_s);
  EXPECT_DOUBLE_EQ(s.deposition_rate_m3ph, plan.deposition_rate_m3ps * 3600.0);

  // The arm: every pose counted, the trajectory checked by FK on every 10th sample.
  EXPECT_EQ(s.ik.poses, poses);
  EXPECT_TRUE(s.ik.solved && s.ik.checked);
  EXPECT_EQ(s.ik.samples_checked, static_cast<int>((arm.trajectory->size() + 9) / 10));
  EXPECT_LT(s.ik.worst_position_error_m, 1e-3);
  EXPECT_LT(s.ik.worst_angle_error_rad, 0.02);
  ASSERT_TRUE(s.trajectory);
  EXPECT_EQ(s.trajectory->samples, arm.trajectory->size());
  EXPECT_FALSE(s.swarm);  // timing.tune_with_pso is off
  // Cycle time: the whole trajectory, its parts adding up to it, over the physical limit.
  ASSERT_TRUE(s.cycle_time_s && s.cycle_time_ratio);
  EXPECT_EQ(*s.cycle_time_s, arm.trajectory->duration_s);
  EXPECT_NEAR(s.trajectory->cycle_time.total_s(), *s.cycle_time_s, 1e-9 * *s.cycle_time_s);
  EXPECT_DOUBLE_EQ(*s.cycle_time_ratio, *s.cycle_time_s / plan.physical_limit_s);
  EXPECT_GT(s.trajectory->max_nozzle_speed_ratio, 0.0);
  EXPECT_GT(s.trajectory->max_nozzle_accel_ratio, 0.0);

  // JSON: report.json's keys in its order.
  const std::string json = s.to_json();
  EXPECT_EQ(json.rfind("{\"mode\":", 0), 0u) << json.substr(0, 40);
  EXPECT_NE(json.find("\"points_in\":1234,"), std::string::npos);
  EXPECT_NE(json.find("\"passes\":" + std::to_string(passes) + ","), std::string::npos);
  std::size_t at = 0;
  for (const char* key : {"\"cells\"", "\"grid_shape\"", "\"levels_before\"", "\"td_before_mm\"", "\"levels_after\"",
                          "\"residual_mm\"", "\"rounds\"", "\"stop_reason\"", "\"spray_time_ratio\"",
                          "\"rounds_detail\"", "\"ik\"", "\"total_time_s\"", "\"cycle_time_s\"",
                          "\"cycle_time_breakdown_s\"", "\"cycle_time_ratio\"", "\"trajectory\""}) {
    const std::size_t k = json.find(key, at);
    ASSERT_NE(k, std::string::npos) << key;
    at = k;
  }
  EXPECT_EQ(json.back(), '}');
}

TEST(JobSummary, WithoutATrajectoryTheErrorIsReported) {
  Config cfg;
  const Surface surface = pit_bay(cfg);
  const Robot robot = Robot::load(cfg.robot);
  ArmPlan arm;
  arm.plan = plan_bay(surface, cfg);
  arm.timing_error = "region 2 waypoint 7: out of reach";
  const JobSummary s = summarise_job(surface, arm, robot, cfg);
  EXPECT_FALSE(s.ik.solved);
  EXPECT_FALSE(s.ik.checked);
  EXPECT_FALSE(s.trajectory);
  const std::string json = s.to_json();
  EXPECT_NE(json.find("\"solved\":false,\"error\":\"region 2 waypoint 7: out of reach\"}"), std::string::npos);
  EXPECT_NE(json.find("\"total_time_s\":null,\"cycle_time_s\":null,\"cycle_time_breakdown_s\":null,"
                      "\"cycle_time_ratio\":null}"),
            std::string::npos)
      << json.substr(json.size() - 120);
  EXPECT_FALSE(s.cycle_time_s);
  EXPECT_FALSE(s.cycle_time_ratio);
  EXPECT_EQ(json.find("\"trajectory\""), std::string::npos);
  // Planned but not executable: the status says so, and the reason is a problem.
  EXPECT_EQ(s.status, "not_executable");
  ASSERT_FALSE(s.problems.empty());
  EXPECT_EQ(s.problems.back().code, "arm_cannot_follow");
  EXPECT_EQ(s.problems.back().message, "the arm cannot follow the plan: region 2 waypoint 7: out of reach");
  EXPECT_EQ(json.rfind("{\"mode\":\"optimal\",\"status\":\"not_executable\",\"problems\":[", 0), 0u) << json.substr(0, 120);

  // A plan of another grid is refused.
  EXPECT_THROW(summarise_job(surface, ArmPlan{}, robot, cfg), std::invalid_argument);
}

// plan_problems against summaries built by hand: each condition on its own, at and just past its
// threshold, and a right plan without any.
TEST(JobSummary, ProblemsNameEveryReasonAPlanIsNotRight) {
  auto codes = [](const JobSummary& s) {
    std::vector<std::string> out;
    for (const auto& p : plan_problems(s)) out.push_back(p.code);
    return out;
  };
  JobSummary ok;
  ok.grid_n_theta = 10;
  ok.grid_n_d = 10;
  ok.cells = 50;  // exactly half the grid holds points
  ok.levels_after = {{-1, 3}, {0, 47}};
  ok.trajectory = TrajectorySummary{};
  ok.trajectory->max_velocity_ratio = ok.trajectory->max_acceleration_ratio = 1.0 + kLimitRatioTolerance;
  ok.trajectory->max_nozzle_speed_ratio = ok.trajectory->max_nozzle_accel_ratio = 1.0;
  EXPECT_EQ(codes(ok), std::vector<std::string>{});

  JobSummary s = ok;
  s.cells = 49;
  EXPECT_EQ(codes(s), std::vector<std::string>{"sparse_grid"});
  EXPECT_EQ(plan_problems(s)[0].message,
            "the scan covers 49 of the grid's 100 cells (less than 50 %): holes are neither graded nor sprayed");
  s = ok;
  s.spot_diameter_m = 0.385;
  s.grid_cell_size_m = 0.04;  // 0.4 m x 0.4 m
  EXPECT_EQ(codes(s), std::vector<std::string>{});
  s.grid_n_theta = 1;  // one row of cells: a line of points along the crown
  s.grid_cell_size_m = 0.05;
  s.grid_n_d = 8;
  s.cells = 8;
  EXPECT_EQ(codes(s), std::vector<std::string>{"narrow_scan"});
  EXPECT_EQ(plan_problems(s)[0].message,
            "the scan's wall spans 0.05 m across by 0.40 m along the axis, narrower than one spray spot (0.39 m): a line or "
            "strip of points, not a bay to spray");
  s = ok;
  s.levels_after = {{0, 40}, {1, 7}, {3, 3}};
  s.unreachable_cells = 4;
  s.stop_reason = "max rounds reached (planner.max_rounds)";
  s.deposit_source = "executed";
  EXPECT_EQ(codes(s), (std::vector<std::string>{"unreachable_cells", "cells_above_level_0"}));
  EXPECT_EQ(plan_problems(s)[1].message,
            "6 more cells are left above level 0 by the executed deposit (stop reason: max rounds reached (planner.max_rounds))");
  s.unreachable_cells = 10;  // all of the cells above level 0 are unreachable: one problem
  EXPECT_EQ(codes(s), std::vector<std::string>{"unreachable_cells"});
  s = ok;
  s.ik.untracked_regions = 2;
  EXPECT_EQ(codes(s), std::vector<std::string>{"untracked_regions"});
  s = ok;
  s.trajectory->max_acceleration_ratio = 1.0 + 2 * kLimitRatioTolerance;
  EXPECT_EQ(codes(s), std::vector<std::string>{"joint_limits"});
  s = ok;
  s.trajectory->max_position_violation_m = 0.01;
  EXPECT_EQ(codes(s), std::vector<std::string>{"joint_limits"});
  s = ok;
  s.trajectory->max_nozzle_speed_ratio = 1.01;
  EXPECT_EQ(codes(s), std::vector<std::string>{"nozzle_limits"});
  s = ok;
  s.ik.solved = false;
  s.ik.error = "IK: waypoint 3 unreachable";
  s.trajectory.reset();
  EXPECT_EQ(codes(s), std::vector<std::string>{"arm_cannot_follow"});
}

TEST(JobSummary, NothingToSprayIsSolved) {
  Config cfg;
  const Surface surface = pit_bay(cfg, 0.0, 0.0);  // flush
  const Robot robot = Robot::load(cfg.robot);
  const ArmPlan arm = plan_for_arm(surface, cfg, robot);
  ASSERT_TRUE(arm.plan.rounds.empty()) << arm.plan.rounds.size();
  const JobSummary s = summarise_job(surface, arm, robot, cfg);
  EXPECT_TRUE(s.ik.solved);
  EXPECT_EQ(s.ik.regions, 0);
  EXPECT_EQ(s.passes, 0);
  EXPECT_DOUBLE_EQ(s.link_length_m, 0.0);
  EXPECT_EQ(s.to_json().find("\"samples_checked\""), std::string::npos);
  EXPECT_EQ(s.status, "ok");
}
