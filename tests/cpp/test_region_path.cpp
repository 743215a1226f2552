// Region paths: turn-around geometry, turn runs, serpentines, pass speed profiles, spray-off gaps,
// stop-and-go joins, the nozzle check and the quintic baseline.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "shotcrete/timing/region_path.hpp"
#include "shotcrete/timing/region_spray.hpp"
#include "shotcrete/timing/sampling.hpp"
#include "timing_fixtures.hpp"

using namespace shotcrete;

using shotcrete::test::axial_region;
using shotcrete::test::kPi;

namespace {

// region_path's options with these leads (and turn runs), the rest at their defaults.
RegionPathOptions leads(double lead_in_m, double lead_out_m, double turn_run_m = 0.0) {
  RegionPathOptions o;
  o.lead_in_m = lead_in_m;
  o.lead_out_m = lead_out_m;
  o.turn_run_m = turn_run_m;
  return o;
}

// turn_around's options from speed v_in to v_out, no spray, no runs.
TurnAroundOptions speeds(double v_in, double v_out) {
  TurnAroundOptions o;
  o.speed_in_mps = v_in;
  o.speed_out_mps = v_out;
  return o;
}

// A 1.2 m pass along +x at height z (waypoints 1 cm apart, the axis up) at speed_mps.
Pass line_along_x(double z, double speed_mps) {
  Pass p;
  for (double x = 0.0; x <= 1.2 + 1e-9; x += 0.01) p.waypoints.push_back({Eigen::Vector3d(x, 0, z), Eigen::Vector3d(0, 0, 1)});
  p.length_m = 1.2;
  p.speed_mps = speed_mps;
  return p;
}

}  // namespace

TEST(Geometry, TurnAroundDiameterIsSpacingAndTangentsContinuous) {
  // Pass a ends at x = 1.0 going +x; pass b starts at x = 1.15 going -x, 0.2 m across (in y).
  NozzlePose ea, sb;
  ea.position_m = {1.0, 0.0, 2.0};
  sb.position_m = {1.15, 0.2, 2.0};
  ea.axis = sb.axis = Eigen::Vector3d(0, 0, 1);
  const auto pieces = turn_around(ea, Eigen::Vector3d::UnitX(), sb, speeds(0.3, 0.2));
  ASSERT_EQ(pieces.size(), 2u);  // extension of a (0.15 m) + arc
  EXPECT_EQ(pieces[0].kind, SegmentKind::Link);
  EXPECT_NEAR(pieces[0].length_m(), 0.15, 1e-12);
  const PathPiece& arc = pieces[1];
  ASSERT_TRUE(arc.is_arc);
  EXPECT_NEAR(2.0 * arc.radius_m, 0.2, 1e-12);  // diameter = spacing
  EXPECT_NEAR(arc.length_m(), kPi * 0.1, 1e-12);
  // Every arc point is r from the centre, the arc bulges beyond the pass ends by r.
  double max_x = -1e9;
  for (int i = 0; i <= 100; ++i) {
    const auto p = arc.pose_at(arc.length_m() * i / 100.0).position_m;
    ASSERT_NEAR((p - arc.center).norm(), 0.1, 1e-12);
    max_x = std::max(max_x, p.x());
  }
  EXPECT_NEAR(max_x, 1.15 + 0.1, 1e-6);
  // Positions and tangents continuous at the joints; the arc ends heading -x onto pass b.
  EXPECT_NEAR((pieces[0].pose_at(0.15).position_m - arc.pose_at(0).position_m).norm(), 0.0, 1e-12);
  EXPECT_NEAR((arc.pose_at(arc.length_m()).position_m - sb.position_m).norm(), 0.0, 1e-12);
  EXPECT_NEAR((pieces[0].tangent_at(0.1) - arc.tangent_at(0.0)).norm(), 0.0, 1e-12);
  EXPECT_NEAR((arc.tangent_at(arc.length_m()) - Eigen::Vector3d(-1, 0, 0)).norm(), 0.0, 1e-12);
  // Tangent is the derivative of position along the arc.
  const double h = 1e-6, s0 = 0.13;
  const Eigen::Vector3d fd = (arc.pose_at(s0 + h).position_m - arc.pose_at(s0 - h).position_m) / (2 * h);
  EXPECT_NEAR((fd - arc.tangent_at(s0)).norm(), 0.0, 1e-6);
  EXPECT_NEAR(arc.curvature_at(0.1), 10.0, 1e-12);
  // The other way round: b sticks out less -> b gets the extension.
  sb.position_m = {0.9, 0.2, 2.0};
  const auto p2 = turn_around(ea, Eigen::Vector3d::UnitX(), sb, speeds(0.3, 0.3));
  ASSERT_EQ(p2.size(), 2u);
  EXPECT_TRUE(p2[0].is_arc);
  EXPECT_NEAR(p2[1].length_m(), 0.1, 1e-12);
  EXPECT_NEAR((p2[1].tangent_at(0.05) - Eigen::Vector3d(-1, 0, 0)).norm(), 0.0, 1e-12);
  // With runs, both sides get a link whatever the offset, and the pieces stay contiguous.
  for (double xb : {0.7, 0.95, 1.05, 1.4}) {
    sb.position_m = {xb, 0.2, 2.0};
    TurnAroundOptions runs = speeds(0.3, 0.3);
    runs.run_out_m = 0.1;
    const auto p3 = turn_around(ea, Eigen::Vector3d::UnitX(), sb, runs);
    ASSERT_EQ(p3.size(), 3u) << xb;
    EXPECT_NEAR((p3[0].pose_at(0).position_m - ea.position_m).norm(), 0.0, 1e-12);
    for (int k = 0; k < 2; ++k)
      EXPECT_NEAR((p3[k].pose_at(p3[k].length_m()).position_m - p3[k + 1].pose_at(0).position_m).norm(), 0.0, 1e-12) << xb;
    EXPECT_NEAR((p3[2].pose_at(p3[2].length_m()).position_m - sb.position_m).norm(), 0.0, 1e-12) << xb;
  }
  sb.position_m = {1.2, 0.0, 2.0};
  EXPECT_THROW(turn_around(ea, Eigen::Vector3d::UnitX(), sb, speeds(0.3, 0.3)), std::invalid_argument);
}

TEST(Geometry, TurnAroundWithUnequalRunsAndSkewedPassesHasNoCorner) {
  // Pass a ends at x = 1.0 going +x; pass b starts 0.2 m across, 0.3 m further on, heading back
  // 10 deg off -x (a wall-following pass is never exactly antiparallel).
  NozzlePose ea, sb;
  ea.position_m = {1.0, 0.0, 2.0};
  sb.position_m = {1.3, 0.2, 2.0};
  ea.axis = sb.axis = Eigen::Vector3d(0, 0, 1);
  const double skew = 10.0 * kPi / 180.0;
  const Eigen::Vector3d db(-std::cos(skew), std::sin(skew), 0.0);
  // Run-out 0.1 m, run-in 0.5 m: the arc sits where both have run on by at least their runs.
  TurnAroundOptions runs = speeds(0.3, 0.2);
  runs.run_out_m = 0.1;
  runs.run_in_m = 0.5;
  runs.dir_b_start = db;
  const auto pieces = turn_around(ea, Eigen::Vector3d::UnitX(), sb, runs);
  ASSERT_EQ(pieces.size(), 3u);
  const PathPiece& arc = pieces[1];
  ASSERT_TRUE(arc.is_arc);
  EXPECT_NEAR(2.0 * arc.radius_m, 0.2, 1e-12);   // diameter = the spacing across, whatever the runs
  EXPECT_NEAR(arc.u.dot(arc.d), 0.0, 1e-12);     // a true half circle
  EXPECT_NEAR(pieces[0].length_m(), 0.3 + 0.5, 1e-12);  // b's run-in decides: 0.3 offset + 0.5
  EXPECT_NEAR((arc.pose_at(0).position_m - sb.position_m).x(), 0.5, 1e-12);
  // Contiguous, ends on b, and no corner anywhere: the direction turns by < 1.5 deg between
  // consecutive 1 mm steps, and the path leaves along +x and arrives along db.
  for (int k = 0; k < 2; ++k)
    EXPECT_NEAR((pieces[k].pose_at(pieces[k].length_m()).position_m - pieces[k + 1].pose_at(0).position_m).norm(), 0.0,
                1e-12);
  const PathPiece& in = pieces[2];
  EXPECT_NEAR((in.pose_at(in.length_m()).position_m - sb.position_m).norm(), 0.0, 1e-12);
  CartesianPath path;
  for (const auto& p : pieces) path.append(p);
  Eigen::Vector3d prev = Eigen::Vector3d::UnitX();
  double worst_deg = 0.0;
  for (double s = 0.0005; s < path.length_m(); s += 0.001) {
    const Eigen::Vector3d t = path.tangent_at(s);
    worst_deg = std::max(worst_deg, std::acos(std::clamp(t.dot(prev), -1.0, 1.0)) * 180.0 / kPi);
    prev = t;
  }
  EXPECT_LT(worst_deg, 1.5);
  EXPECT_LT(std::acos(std::clamp(prev.dot(db), -1.0, 1.0)) * 180.0 / kPi, 1.0);
  // Without dir_b the run-in stays straight along -x (the antiparallel case).
  runs.dir_b_start.setZero();
  const auto straight = turn_around(ea, Eigen::Vector3d::UnitX(), sb, runs);
  EXPECT_EQ(straight[2].poses.size(), 2u);
}

TEST(Region, TurnRunsSizedForTheSpeedChange) {
  // Passes at 0.8 m/s, 0.2 m apart: the arc (r = 0.1 m) is capped at sqrt(0.5 * 0.1) = 0.224 m/s
  // and the runs must bring 0.8 m/s down to it at 0.5 m/s^2: (0.64 - 0.05) / 0.5 = 1.18 m.
  const auto passes = axial_region(2, 1.2, 0.2, 0.0, 1.2, {0.8}, 4.6, 4.6 + 1e-9);
  const double a = 0.5;
  RegionPathOptions opt = leads(0.1, 0.1, 0.1);
  opt.turn_accel_mps2 = a;
  const CartesianPath path = region_path(passes, opt);
  TimingParams prm = TimingParams::from_config(TimingConfig{});
  prm.speed_change_accel_mps2 = a;
  prm.turn_accel_mps2 = a;
  const SpeedProfile prof = region_profile(path, prm);
  int runs = 0;
  for (std::size_t i = 0; i < path.pieces().size(); ++i) {
    const auto& p = path.pieces()[i];
    if (p.kind != SegmentKind::Link) continue;
    ++runs;
    const double r = 0.5 * (passes[1].waypoints.front().position_m - passes[0].waypoints.back().position_m).norm();
    const double vt = std::sqrt(a * r);
    EXPECT_NEAR(p.length_m(), (0.64 - vt * vt) / a, 1e-6);
    const double t0 = prof.time_at_distance(path.piece_start_m(i));
    const double t1 = prof.time_at_distance(path.piece_start_m(i) + p.length_m());
    double peak = 0.0;
    for (double t = t0; t <= t1; t += 0.001) peak = std::max(peak, std::abs(prof.at(t).a_mps2));
    EXPECT_LT(peak, a + 1e-3);
    EXPECT_GT(peak, 0.9 * a);
  }
  EXPECT_EQ(runs, 2);
  // A gap scale of 0.5 halves the turn's acceleration: longer runs, and the profile caps the arc
  // speed at the eased centripetal acceleration (the arc carries its own).
  opt.gap_accel_scale = {0.5};
  const CartesianPath eased = region_path(passes, opt);
  const SpeedProfile eased_prof = region_profile(eased, prm);
  for (std::size_t i = 0; i < eased.pieces().size(); ++i) {
    const auto& p = eased.pieces()[i];
    const double r = 0.5 * (passes[1].waypoints.front().position_m - passes[0].waypoints.back().position_m).norm();
    if (p.kind == SegmentKind::Link) {
      EXPECT_NEAR(p.length_m(), (0.64 - 0.5 * a * r) / (0.5 * a), 1e-6);
    }
    if (p.kind != SegmentKind::Turn) continue;
    EXPECT_NEAR(p.accel_scale, 0.5, 1e-12);
    const double mid = eased_prof.time_at_distance(eased.piece_start_m(i) + 0.5 * p.length_m());
    EXPECT_NEAR(eased_prof.at(mid).v_mps, std::sqrt(0.5 * a * r), 1e-6);
  }
  // Without the acceleration the runs keep turn_run_m.
  const CartesianPath fixed = region_path(passes, leads(0.1, 0.1, 0.1));
  for (const auto& p : fixed.pieces()) {
    if (p.kind == SegmentKind::Link) {
      EXPECT_NEAR(p.length_m(), 0.1, 1e-9);
    }
  }
}

TEST(Geometry, CurvedPassesAreSampledWithoutCornerSpikes) {
  // A pass curving at r = 0.12 m (waypoints 1 cm apart, the axis the outward normal) as the
  // planner writes it; sampled 4.7 mm apart (0.235 m/s at 50 Hz). Straight segments met their
  // corners every other sample: second differences of 0 and 2 / r, joint-acceleration spikes.
  const double r = 0.12, dth = 0.01 / r;
  Pass pass;
  for (int k = 0; k <= 24; ++k) {
    const Eigen::Vector3d n(std::cos(k * dth), std::sin(k * dth), 0.0);
    pass.waypoints.push_back({r * n, n});
  }
  pass.speed_mps = 0.235;
  pass.length_m = 0.24;
  const CartesianPath path = region_path({pass}, leads(0.1, 0.1));
  const PathPiece* piece = nullptr;
  for (const auto& p : path.pieces())
    if (p.kind == SegmentKind::Pass) piece = &p;
  ASSERT_NE(piece, nullptr);
  for (std::size_t k = 0; k < pass.waypoints.size(); ++k) {  // through every waypoint
    const NozzlePose at = piece->pose_at(piece->cum_m[k]);
    EXPECT_LT((at.position_m - pass.waypoints[k].position_m).norm(), 1e-12);
    EXPECT_LT((at.axis - pass.waypoints[k].axis).norm(), 1e-12);
  }
  const double h = 0.0047;
  for (double s = 0.02; s + 0.02 < piece->length_m(); s += 0.0011) {
    const NozzlePose a = piece->pose_at(s - h), b = piece->pose_at(s), c = piece->pose_at(s + h);
    EXPECT_NEAR((a.position_m - 2.0 * b.position_m + c.position_m).norm() / (h * h), 1.0 / r, 0.1 / r) << s;
    EXPECT_NEAR(b.position_m.norm(), r, 2e-5) << s;  // on the circle within 0.02 mm (chords: 0.1 mm in)
    EXPECT_NEAR(std::acos(std::min(1.0, b.axis.dot(c.axis))) / h, 1.0 / r, 0.1 / r) << s;  // the axis turns evenly
    EXPECT_NEAR((a.axis - 2.0 * b.axis + c.axis).norm() / (h * h), 1.0 / (r * r), 0.1 / (r * r)) << s;
  }
  // A corner of more than 30 deg stays a corner (both legs straight), and a segment twice as long
  // as its neighbour does not bulge.
  Pass ell;
  for (const Eigen::Vector3d& p : {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0.1, 0, 0), Eigen::Vector3d(0.2, 0, 0),
                                   Eigen::Vector3d(0.2, 0.1, 0), Eigen::Vector3d(0.2, 0.2, 0), Eigen::Vector3d(0.21, 0.21, 0),
                                   Eigen::Vector3d(0.22, 0.6, 0)})
    ell.waypoints.push_back({p, Eigen::Vector3d(0, 0, 1)});
  ell.speed_mps = 0.2;
  ell.length_m = 1.0;
  const CartesianPath lp = region_path({ell}, leads(0.1, 0.1));
  for (const auto& p : lp.pieces()) {
    if (p.kind != SegmentKind::Pass) continue;
    for (double s = 0.0; s <= p.cum_m[2]; s += 0.005) EXPECT_NEAR(p.pose_at(s).position_m.y(), 0.0, 1e-12) << s;
    for (double s = p.cum_m[2]; s <= p.cum_m[4]; s += 0.005) EXPECT_NEAR(p.pose_at(s).position_m.x(), 0.2, 1e-12) << s;
    const double mid = 0.5 * (p.cum_m[5] + p.cum_m[6]);
    EXPECT_LT((p.pose_at(mid).position_m - 0.5 * (ell.waypoints[5].position_m + ell.waypoints[6].position_m)).norm(), 1e-12);
  }
}

TEST(RegionPath, EasedJoinsRunLongerWhereTheMinimumRunBinds) {
  // Passes at 0.2 m/s: a stop at 0.5 m/s^2 needs 0.08 m, less than the 0.1 m minimum run, so the
  // run is 0.1 m whatever the acceleration. An eased gap (scale 0.5) runs 0.2 m and its stop is
  // about half as hard: before, easing left it as it was (a slew at 1.006x its limit through six
  // easings on the default bay, then two re-plans of the whole bay). A turn's runs stay as sized:
  // there the arc, eased by its speed, carries the excess.
  const auto line = [](double z) { return line_along_x(z, 0.2); };
  RegionPathOptions stop = leads(0.1, 0.1, 0.1);
  stop.stop_accel_mps2 = 0.5;
  stop.gap_accel_scale = {1.0, 0.5};
  const CartesianPath eased = region_path({line(4.6), line(4.8), line(5.0)}, stop);
  TimingParams prm = TimingParams::from_config(TimingConfig{});
  prm.k1 = prm.k2 = 0.5;
  const SpeedProfile prof = region_profile(eased, prm);
  std::vector<double> outs, ins, peaks;
  for (std::size_t i = 0; i < eased.pieces().size(); ++i) {
    const auto& p = eased.pieces()[i];
    if (p.motion == PieceMotion::StartFromRest) ins.push_back(p.length_m());
    if (p.motion != PieceMotion::StopAtEnd) continue;
    outs.push_back(p.length_m());
    const double t0 = prof.time_at_distance(eased.piece_start_m(i)), t1 = prof.time_at_distance(eased.piece_start_m(i + 1));
    double peak = 0.0;
    for (double t = t0; t <= t1; t += 0.001) peak = std::max(peak, std::abs(prof.at(t).a_mps2));
    peaks.push_back(peak);
  }
  ASSERT_EQ(outs.size(), 2u);
  ASSERT_EQ(ins.size(), 2u);
  EXPECT_NEAR(outs[0], 0.1, 1e-9);
  EXPECT_NEAR(ins[0], 0.1, 1e-9);
  EXPECT_NEAR(outs[1], 0.2, 1e-9);
  EXPECT_NEAR(ins[1], 0.2, 1e-9);
  EXPECT_GT(peaks[0], 0.0);
  EXPECT_NEAR(peaks[1] / peaks[0], 0.5, 0.05);
}

TEST(Region, SerpentineNeverStopsAndKeepsPassSpeeds) {
  const auto passes = axial_region(6, 1.2, 0.2, 0.0, 1.2, {0.2, 0.3, 0.25});
  TimingParams prm;
  prm.k1 = 0.6;
  prm.k2 = 0.4;
  prm.start_length_m = prm.end_length_m = 0.12;
  const CartesianPath path = region_path(passes, leads(prm.start_length_m, prm.end_length_m));
  const SpeedProfile prof = region_profile(path, prm);
  EXPECT_NEAR(prof.length_m(), path.length_m(), 1e-9);
  // Path length: passes + leads + half circles of the spacing at the nozzle radius.
  const double chord = 2.0 * 4.6 * std::sin(0.5 * 0.2 / 5.6);
  EXPECT_NEAR(path.length_m(), 6 * 1.2 + 0.24 + 5 * kPi * chord / 2.0, 1e-6);
  const CartesianSamples cs = sample_path(path, prof, 200.0);
  ASSERT_GT(cs.t_s.size(), 100u);
  double max_dv = 0.0, max_step = 0.0;
  std::vector<double> pass_time(6, 0.0);
  const auto dw = spray_dwells(cs.t_s, cs.spraying);
  for (std::size_t i = 0; i < cs.t_s.size(); ++i) {
    if (i > 0) {
      max_dv = std::max(max_dv, std::abs(cs.speed_mps[i] - cs.speed_mps[i - 1]));
      max_step = std::max(max_step, cs.t_s[i] - cs.t_s[i - 1]);
      // Position continuity: the nozzle moves at most v dt between samples.
      ASSERT_LE((cs.nozzle[i].position_m - cs.nozzle[i - 1].position_m).norm(), 0.3 * (cs.t_s[i] - cs.t_s[i - 1]) + 1e-9);
    }
    if (cs.kind[i] != static_cast<char>(SegmentKind::Lead)) {
      ASSERT_GT(cs.speed_mps[i], 0.05) << "stopped inside the region at t = " << cs.t_s[i];
    }
    if (cs.kind[i] == static_cast<char>(SegmentKind::Pass)) {
      ASSERT_TRUE(cs.spraying[i]);
      ASSERT_NEAR(cs.speed_mps[i], passes[static_cast<std::size_t>(cs.pass_index[i])].speed_mps, 1e-12);
      pass_time[static_cast<std::size_t>(cs.pass_index[i])] += dw[i];
    } else {
      ASSERT_FALSE(cs.spraying[i]);
      ASSERT_EQ(cs.pass_index[i], -1);
    }
  }
  EXPECT_LE(max_step, 1.0 / 200.0 + 1e-12);
  EXPECT_LT(max_dv, 0.01);  // no speed jumps at 200 Hz
  // Dwells add up to each pass's duration within one sample.
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(pass_time[static_cast<std::size_t>(i)], 1.2 / passes[static_cast<std::size_t>(i)].speed_mps, 1.0 / 200.0);
  EXPECT_NEAR(cs.speed_mps.front(), 0.0, 1e-12);
  EXPECT_NEAR(cs.speed_mps.back(), 0.0, 1e-12);
  // With runs the arc speed is capped by the centripetal limit: sqrt(a r) = 0.2026 m/s < 0.3 m/s.
  {
    const CartesianPath with_runs = region_path(passes, leads(prm.start_length_m, prm.end_length_m, 0.1));
    const SpeedProfile capped = region_profile(with_runs, prm);
    const CartesianSamples c2 = sample_path(with_runs, capped, 500.0);
    double amax = 0.0;
    for (std::size_t i = 0; i < c2.t_s.size(); ++i)
      if (c2.kind[i] == static_cast<char>(SegmentKind::Turn)) amax = std::max(amax, c2.normal_accel_mps2[i]);
    EXPECT_LE(amax, 0.5 + 1e-9);
    EXPECT_GT(amax, 0.49);
  }
  // Turn speed > 0: the middle of each arc runs at the turn speed.
  prm.turn_speed_mps = 0.5;
  prm.speed_change_accel_mps2 = 10.0;  // the arc speed cap sqrt(a r) above 0.5 m/s
  const SpeedProfile fast = region_profile(path, prm);
  EXPECT_LT(fast.duration_s(), prof.duration_s());
  double vmax_turn = 0.0;
  for (const auto& s : sample_path(path, fast, 500.0).speed_mps) vmax_turn = std::max(vmax_turn, s);
  EXPECT_NEAR(vmax_turn, 0.5, 1e-4);
}

TEST(Region, TurnRunsCarryTheSpeedChange) {
  const auto passes = axial_region(3, 1.0, 0.2, 0.0, 1.0, {0.3, 0.2});
  TimingParams prm;
  prm.turn_speed_mps = 0.12;
  const CartesianPath path = region_path(passes, leads(0.1, 0.1, 0.15));
  const SpeedProfile prof = region_profile(path, prm);
  EXPECT_NEAR(prof.length_m(), path.length_m(), 1e-9);
  // Every arc is run entirely at the turn speed; the speed is continuous (max step at 1 kHz).
  const CartesianSamples cs = sample_path(path, prof, 1000.0);
  double max_dv = 0.0;
  int on_arc = 0;
  for (std::size_t i = 0; i < cs.t_s.size(); ++i) {
    if (i > 0) max_dv = std::max(max_dv, std::abs(cs.speed_mps[i] - cs.speed_mps[i - 1]));
    if (cs.kind[i] == static_cast<char>(SegmentKind::Turn)) {
      ASSERT_NEAR(cs.speed_mps[i], 0.12, 1e-9);
      ++on_arc;
    }
    if (cs.kind[i] == static_cast<char>(SegmentKind::Pass)) {
      ASSERT_NEAR(cs.speed_mps[i], passes[static_cast<std::size_t>(cs.pass_index[i])].speed_mps, 1e-12);
    }
  }
  EXPECT_GT(on_arc, 100);
  EXPECT_LT(max_dv, 3e-3);  // peak 2.7 m/s^2 (the lead-in start), no jumps
  // Runs of 0.15 m on both sides of each of the 2 arcs.
  int runs = 0;
  for (const auto& p : path.pieces())
    if (p.kind == SegmentKind::Link) {
      EXPECT_NEAR(p.length_m(), 0.15, 1e-9);
      ++runs;
    }
  EXPECT_EQ(runs, 4);
}

// Turn-arounds at their own speed last at least min_turn_s (the pump's shortest off spell: a
// shorter turn is sprayed through): the arc slows until runs + arc take that long, measured on
// the sampled path against the unfloored profile and the closed form of the turn's duration.
TEST(Region, TurnsAtTheirOwnSpeedLastTheMinimumTurnTime) {
  const auto passes = axial_region(3, 1.0, 0.2, 0.0, 1.0, {0.3, 0.2});
  TimingParams prm;
  prm.turn_speed_mps = 0.5;
  prm.turn_accel_mps2 = 10.0;  // the centripetal cap sqrt(a r) = 1 m/s above the turn speed
  const CartesianPath path = region_path(passes, leads(0.1, 0.1, 0.15));
  // Off time between passes: from the last sample of pass i to the first of pass i + 1.
  auto turn_times = [&](const TimingParams& p, double* arc_speed) {
    const CartesianSamples cs = sample_path(path, region_profile(path, p), 1000.0);
    std::vector<double> out;
    double last_end = -1.0;
    int last_pass = -1;
    *arc_speed = 0.0;
    for (std::size_t i = 0; i < cs.t_s.size(); ++i) {
      if (cs.kind[i] == static_cast<char>(SegmentKind::Turn)) *arc_speed = std::max(*arc_speed, cs.speed_mps[i]);
      if (cs.kind[i] != static_cast<char>(SegmentKind::Pass)) continue;
      if (last_pass >= 0 && cs.pass_index[i] != last_pass) out.push_back(cs.t_s[i] - last_end);
      last_pass = cs.pass_index[i];
      last_end = cs.t_s[i];
    }
    return out;
  };
  double v_free = 0.0, v_floor = 0.0;
  const auto free = turn_times(prm, &v_free);
  ASSERT_EQ(free.size(), 2u);
  EXPECT_NEAR(v_free, 0.5, 1e-3);
  // Closed form at arc speed u: each run (0.15 m) at its mean speed, the arc (pi r; r = half the
  // passes' spacing at the nozzle) at u.
  double arc_m = 0.0;
  for (const auto& p : path.pieces())
    if (p.kind == SegmentKind::Turn) arc_m = p.length_m();
  ASSERT_NEAR(arc_m, kPi * 0.5 * 0.2 * 4.6 / 5.6, 1e-3);
  auto duration = [&](double u, double va, double vb) { return 0.15 / (0.5 * (va + u)) + arc_m / u + 0.15 / (0.5 * (u + vb)); };
  for (std::size_t k = 0; k < 2; ++k) EXPECT_NEAR(free[k], duration(0.5, k == 0 ? 0.3 : 0.2, k == 0 ? 0.2 : 0.3), 2e-3);
  prm.min_turn_s = 2.1;
  const auto floored = turn_times(prm, &v_floor);
  ASSERT_EQ(floored.size(), 2u);
  for (std::size_t k = 0; k < 2; ++k) {
    EXPECT_LT(free[k], 2.1);
    EXPECT_NEAR(floored[k], 2.1, 2e-3);
  }
  // Both turns join a 0.3 and a 0.2 m/s pass: the same arc speed solves the closed form.
  EXPECT_LT(v_floor, 0.5);
  EXPECT_NEAR(duration(v_floor, 0.3, 0.2), 2.1, 1e-3);
  // A turn already longer than the minimum keeps its speed.
  prm.min_turn_s = 0.5;
  double v_kept = 0.0;
  turn_times(prm, &v_kept);
  EXPECT_NEAR(v_kept, 0.5, 1e-3);
}

// Between passes faster than the turn the arc can only slow if the runs leave room to brake:
// region_path sizes them for the arc speed at which the turn lasts min_turn_s, and the profile
// then takes that speed (turn acceleration kept on the runs and the arc).
TEST(Region, TurnRunsLeaveRoomForTheMinimumTurnTime) {
  // Arc radius 0.082 m: the centripetal cap sqrt(2 r) = 0.405 m/s under the 0.45 m/s passes; runs
  // of 0.02 m are all the change needs, and the turn takes 0.73 s.
  const auto passes = axial_region(3, 1.0, 0.2, 0.0, 1.0, {0.45, 0.45});
  RegionPathOptions o = leads(0.3, 0.3, 0.02);
  o.turn_speed_mps = 0.5;
  o.turn_accel_mps2 = 2.0;
  TimingParams prm;
  prm.turn_speed_mps = 0.5;
  prm.turn_accel_mps2 = 2.0;
  prm.start_length_m = prm.end_length_m = 0.3;
  auto off_times = [&](const CartesianPath& path, double* peak_accel) {
    const CartesianSamples cs = sample_path(path, region_profile(path, prm), 1000.0);
    std::vector<double> out;
    int last = -1;
    double end = 0.0;
    *peak_accel = 0.0;
    for (std::size_t i = 0; i < cs.t_s.size(); ++i) {
      const char k = cs.kind[i];
      if (k == static_cast<char>(SegmentKind::Turn) || (k == static_cast<char>(SegmentKind::Link) && i > 0)) {
        const double dv = std::abs(cs.speed_mps[i] - cs.speed_mps[i - 1]) / (cs.t_s[i] - cs.t_s[i - 1]);
        *peak_accel = std::max({*peak_accel, dv, cs.normal_accel_mps2[i]});
      }
      if (k != static_cast<char>(SegmentKind::Pass)) continue;
      if (last >= 0 && cs.pass_index[i] != last) out.push_back(cs.t_s[i] - end);
      last = cs.pass_index[i];
      end = cs.t_s[i];
    }
    return out;
  };
  double a_free = 0.0, a_floor = 0.0;
  const auto free = off_times(region_path(passes, o), &a_free);
  o.min_turn_s = prm.min_turn_s = 2.1;
  const auto floored = off_times(region_path(passes, o), &a_floor);
  ASSERT_EQ(free.size(), 2u);
  ASSERT_EQ(floored.size(), 2u);
  for (std::size_t k = 0; k < 2; ++k) {
    EXPECT_NEAR(free[k], 2 * 0.02 / 0.4276 + kPi * 0.0821 / 0.4053, 0.01);
    EXPECT_NEAR(floored[k], 2.1, 5e-3);
  }
  EXPECT_LE(a_floor, 2.0 + 0.02);  // cycloid peaks sampled at 1 kHz
}

TEST(Region, PassSpeedProfileKeptWithSmoothChanges) {
  // One pass of 1 m: waypoints 0..50 at 0.2 m/s, 51..100 at 0.4 m/s (optimal-mode speed profile).
  auto passes = axial_region(1, 1.0, 0.2, 0.0, 1.0, {0.3});
  Pass& p = passes[0];
  for (std::size_t k = 0; k < p.waypoints.size(); ++k) p.speed_profile_mps.push_back(k <= 50 ? 0.2 : 0.4);
  TimingParams prm;
  prm.speed_change_accel_mps2 = 0.5;
  const CartesianPath path = region_path(passes, leads(0.1, 0.1));
  const SpeedProfile prof = region_profile(path, prm);
  // Planner's dwell semantics: waypoint k owns half of each neighbouring interval at its speed, so
  // the switch sits at s = 0.505 m; the cycloid spans h = |dv| (va + vb) / (2 a) = 0.12 m each side.
  double planned = 0.0;
  for (std::size_t k = 0; k + 1 < p.waypoints.size(); ++k) {
    const double len = (p.waypoints[k + 1].position_m - p.waypoints[k].position_m).norm();
    planned += 0.5 * len / p.speed_at(k) + 0.5 * len / p.speed_at(k + 1);
  }
  const double h = 0.2 * 0.6 / (2 * 0.5);
  const double expected = planned - (h / 0.2 + h / 0.4) + 2 * h / 0.3;
  const double t0 = prof.time_at_distance(path.piece_start_m(1)), t1 = prof.time_at_distance(path.piece_start_m(2));
  EXPECT_NEAR(t1 - t0, expected, 1e-6);
  // Away from the switch the planned speeds hold; the change is continuous with peak 0.5 m/s^2.
  const double s0 = path.piece_start_m(1);
  EXPECT_NEAR(prof.at(prof.time_at_distance(s0 + 0.2)).v_mps, 0.2, 1e-12);
  EXPECT_NEAR(prof.at(prof.time_at_distance(s0 + 0.8)).v_mps, 0.4, 1e-12);
  const double ta = prof.time_at_distance(s0 + 0.505 - h), tb = prof.time_at_distance(s0 + 0.505 + h);
  EXPECT_NEAR(tb - ta, 2 * h / 0.3, 1e-6);  // the change spans exactly the 2 h around the switch
  EXPECT_NEAR(prof.at(0.5 * (ta + tb)).v_mps, 0.3, 1e-6);
  EXPECT_NEAR(prof.at(ta).v_mps, 0.2, 1e-6);
  EXPECT_NEAR(prof.at(tb).v_mps, 0.4, 1e-6);
  double amax = 0.0;
  for (const auto& pc : prof.pieces())
    if (pc.v0_mps == 0.2 && pc.v1_mps == 0.4) amax = pc.peak_accel_mps2();
  EXPECT_NEAR(amax, 0.5, 1e-9);
  passes[0].speed_profile_mps.pop_back();
  EXPECT_THROW(region_path(passes, leads(0.1, 0.1)), std::invalid_argument);
}

TEST(Region, NozzleCheckSeesCentripetalAcceleration) {
  const auto passes = axial_region(2, 1.0, 0.2, 0.0, 1.0, {0.4});
  TimingParams prm;
  prm.k1 = 1.0;
  prm.k2 = 0.0;
  prm.start_length_m = prm.end_length_m = 0.5;  // gentle start/stop: the arc dominates
  prm.speed_change_accel_mps2 = 10.0;           // no arc speed cap
  const CartesianPath path = region_path(passes, leads(0.5, 0.5));
  const auto c = check_nozzle(path, region_profile(path, prm), NozzleLimits{1.0, 1.0});
  double r = 0.0;
  for (const auto& p : path.pieces())
    if (p.is_arc) r = p.radius_m;
  ASSERT_GT(r, 0.0);
  EXPECT_NEAR(c.max_accel_mps2, 0.4 * 0.4 / r, 1e-6);
  EXPECT_NEAR(c.max_speed_mps, 0.4, 1e-12);
  EXPECT_EQ(c.ok(), 0.16 / r <= 1.0);
}

TEST(Baseline, FullStopsAtEveryCorner) {
  const auto passes = axial_region(4, 1.2, 0.2, 0.0, 1.2, {0.3});
  const BaselinePath b = quintic_baseline(passes, 0.5, 0.3);
  EXPECT_NEAR(b.profile.length_m(), b.path.length_m(), 1e-9);
  // The speed is zero where each piece of the baseline path starts (lead-in starts, step-overs).
  int stops = 0;
  for (std::size_t i = 0; i < b.path.pieces().size(); ++i) {
    const auto& p = b.path.pieces()[i];
    if (p.kind == SegmentKind::Link || (p.kind == SegmentKind::Lead && (i == 0 || b.path.pieces()[i - 1].kind == SegmentKind::Link))) {
      const double t = b.profile.time_at_distance(b.path.piece_start_m(i));
      EXPECT_NEAR(b.profile.at(t).v_mps, 0.0, 1e-6);
      ++stops;
    }
  }
  EXPECT_EQ(stops, 4 + 3);
  const auto c = check_nozzle(b.path, b.profile, NozzleLimits{1.0, 0.5});
  EXPECT_NEAR(c.max_accel_mps2, 0.5, 1e-9);  // accelerations sized to the limit
  // Passes are sprayed at their speed.
  for (const auto& s : [&] { return sample_path(b.path, b.profile, 100.0); }().speed_mps) EXPECT_LE(s, 0.3 + 1e-12);
  // Cycloid + arcs with the same acceleration limit is faster.
  TimingParams prm;
  prm.k1 = 1.0;
  prm.k2 = 0.0;
  prm.start_length_m = prm.end_length_m = 0.5 * 0.3 * (2.0 * 0.3 / 0.5);  // peak 0.5 m/s^2
  const CartesianPath path = region_path(passes, leads(prm.start_length_m, prm.end_length_m));
  EXPECT_LT(region_profile(path, prm).duration_s(), b.profile.duration_s());
}

TEST(RegionPath, SprayOffGapOnTheSameLineIsCrossedWithoutStopping) {
  // Two passes on one line with a 0.2 m gap (the optimal planner switched the spray off there).
  auto line = [](double x0, double x1) {
    Pass p;
    for (double x = x0; x <= x1 + 1e-9; x += 0.01) p.waypoints.push_back({Eigen::Vector3d(x, 0, 4.6), Eigen::Vector3d(0, 0, 1)});
    p.length_m = x1 - x0;
    return p;
  };
  Pass a = line(0.0, 0.4), b = line(0.6, 1.2);
  a.speed_mps = 0.2;
  b.speed_mps = 0.3;
  const CartesianPath path = region_path({a, b}, leads(0.1, 0.1, 0.1));
  int gaps = 0;
  for (const auto& piece : path.pieces())
    if (piece.motion == PieceMotion::SprayOffGap) {
      ++gaps;
      EXPECT_FALSE(piece.spraying);
      EXPECT_NEAR(piece.length_m(), 0.2, 1e-9);
    }
  EXPECT_EQ(gaps, 1);
  const SpeedProfile prof = region_profile(path, TimingParams::from_config(TimingConfig{}));
  EXPECT_NEAR(prof.length_m(), path.length_m(), 1e-6);
  // The nozzle never stops between the lead-in and the lead-out, and the speed goes 0.2 -> 0.3.
  double vmin = 1e9;
  for (double t = 0.2 * prof.duration_s(); t < 0.8 * prof.duration_s(); t += 0.01) vmin = std::min(vmin, prof.at(t).v_mps);
  EXPECT_GT(vmin, 0.19);
  // On the passes the planned speeds hold exactly.
  const CartesianSamples cs = sample_path(path, prof, 500.0);
  for (std::size_t i = 0; i < cs.t_s.size(); ++i)
    if (cs.kind[i] == static_cast<char>(SegmentKind::Pass)) {
      ASSERT_NEAR(cs.speed_mps[i], cs.pass_index[i] == 0 ? 0.2 : 0.3, 1e-12);
    }
}

// A leaning nozzle's line is no straight one: where the lean fades toward a face its standoff
// point drifts across the line (the face scene: 2-4 cm over a 0.14 m gap, ends 10-30 deg apart).
// Two runs of one planner line (Pass::line) across such a drift are still joined by a spray-off
// gap along it, not by a stop-and-go (which at the slow passes' 0.04 m/s took 10-13 s); runs of
// two lines on the same drift, and a run coming back along its line, are not.
TEST(RegionPath, ASprayOffGapFollowsALineThatDriftsAcross) {
  auto drifting = [](double x0, double x1, int line) {  // z = 4.6 + 0.3 x^2: 13-18 deg off x at the gap
    Pass p;
    for (double x = x0; x <= x1 + 1e-9; x += 0.01)
      p.waypoints.push_back({Eigen::Vector3d(x, 0, 4.6 + 0.3 * x * x), Eigen::Vector3d(0, 0, 1)});
    p.length_m = polyline_length(p.waypoints);
    p.speed_mps = 0.04;
    p.line = line;
    return p;
  };
  auto motions = [](const std::vector<Pass>& passes) {
    std::vector<PieceMotion> out;
    const CartesianPath path = region_path(passes, leads(0.1, 0.1, 0.1));
    for (const auto& piece : path.pieces())
      if (piece.motion != PieceMotion::ByKind) out.push_back(piece.motion);
    return out;
  };
  const Pass a = drifting(0.0, 0.4, 3), b = drifting(0.54, 1.0, 3);
  // The old test (directions within 8 deg, less than 1 mm across) misses it: 5 mm across.
  const Eigen::Vector3d da = (a.waypoints.back().position_m - a.waypoints[a.waypoints.size() - 2].position_m).normalized();
  const Eigen::Vector3d gap = b.waypoints.front().position_m - a.waypoints.back().position_m;
  ASSERT_GT((gap - gap.dot(da) * da).norm(), 1e-3);
  EXPECT_EQ(motions({a, b}), std::vector<PieceMotion>{PieceMotion::SprayOffGap});
  const CartesianPath path = region_path({a, b}, leads(0.1, 0.1, 0.1));
  const SpeedProfile prof = region_profile(path, TimingParams::from_config(TimingConfig{}));
  double vmin = 1e9;  // never at rest between the lead-in and the lead-out
  for (double t = 0.2 * prof.duration_s(); t < 0.8 * prof.duration_s(); t += 0.01) vmin = std::min(vmin, prof.at(t).v_mps);
  EXPECT_GT(vmin, 0.039);
  // The gap's curve leaves a on its end direction and meets b on its start direction.
  for (const auto& piece : path.pieces())
    if (piece.motion == PieceMotion::SprayOffGap) {
      EXPECT_LT((piece.poses.front().position_m - a.waypoints.back().position_m).norm(), 1e-9);
      EXPECT_LT((piece.poses.back().position_m - b.waypoints.front().position_m).norm(), 1e-9);
    }
  // Two lines: stop and go.
  const std::vector<PieceMotion> stop_and_go = {PieceMotion::StopAtEnd, PieceMotion::RestToRest, PieceMotion::StartFromRest};
  EXPECT_EQ(motions({a, drifting(0.54, 1.0, 4)}), stop_and_go);
  // The same line, the second run behind the first one's end: stop and go too.
  EXPECT_EQ(motions({drifting(0.54, 1.0, 3), a}), stop_and_go);
  // Passes of no planner line (Pass::line -1, as built outside plan_passes), and runs of one line
  // more than 0.5 m apart (crossed at the passes' speeds, slower than a stop-and-go): stop and go.
  EXPECT_EQ(Pass{}.line, -1);
  EXPECT_EQ(motions({drifting(0.0, 0.4, -1), drifting(0.54, 1.0, -1)}), stop_and_go);
  EXPECT_EQ(motions({a, drifting(0.95, 1.4, 3)}), stop_and_go);
}

TEST(RegionPath, StopAndGoRunsGrowWithThePassSpeed) {
  // Two passes along +x on neighbouring lines (not a serpentine): stop-and-go between them. At
  // 0.8 m/s and 0.5 m/s^2 the plain cycloidal stop needs 0.8^2 / 0.5 = 1.28 m (a k2 = 0.5 cruise
  // would need 3.84 m).
  const auto line = [](double z) { return line_along_x(z, 0.8); };
  const std::vector<Pass> passes = {line(4.6), line(4.8)};
  const CartesianPath fixed = region_path(passes, leads(0.1, 0.1, 0.1));
  RegionPathOptions stop = leads(0.1, 0.1, 0.1);
  stop.stop_accel_mps2 = 0.5;
  const CartesianPath grown = region_path(passes, stop);
  double out_fixed = 0, out_grown = 0;
  for (const auto& p : fixed.pieces())
    if (p.motion == PieceMotion::StopAtEnd) out_fixed = p.length_m();
  for (const auto& p : grown.pieces())
    if (p.motion == PieceMotion::StopAtEnd) out_grown = p.length_m();
  EXPECT_NEAR(out_fixed, 0.1, 1e-9);
  EXPECT_NEAR(out_grown, 0.8 * 0.8 / 0.5, 1e-9);
  // The stop then peaks at the acceleration limit.
  TimingParams prm = TimingParams::from_config(TimingConfig{});
  prm.k1 = prm.k2 = 0.5;
  const SpeedProfile prof = region_profile(grown, prm);
  ASSERT_EQ(grown.pieces()[2].motion, PieceMotion::StopAtEnd);  // lead-in, pass, run-out, ...
  const double t_from = prof.time_at_distance(grown.piece_start_m(2)), t_stop = prof.time_at_distance(grown.piece_start_m(3));
  double peak = 0.0;
  for (double t = t_from; t <= t_stop; t += 0.001) peak = std::max(peak, std::abs(prof.at(t).a_mps2));
  EXPECT_GT(peak, 0.45);
  EXPECT_LT(peak, 0.5 + 1e-3);
  // Per-gap scales ease only their own gap: a third line, the second gap at half the acceleration.
  const std::vector<Pass> three = {line(4.6), line(4.8), line(5.0)};
  stop.gap_accel_scale = {1.0, 0.5};
  const CartesianPath eased = region_path(three, stop);
  std::vector<double> outs, ins;
  for (const auto& p : eased.pieces()) {
    if (p.motion == PieceMotion::StopAtEnd) outs.push_back(p.length_m());
    if (p.motion == PieceMotion::StartFromRest) ins.push_back(p.length_m());
  }
  ASSERT_EQ(outs.size(), 2u);
  ASSERT_EQ(ins.size(), 2u);
  EXPECT_NEAR(outs[0], 0.64 / 0.5, 1e-9);
  EXPECT_NEAR(ins[0], 0.64 / 0.5, 1e-9);
  EXPECT_NEAR(outs[1], 0.64 / 0.25, 1e-9);
  EXPECT_NEAR(ins[1], 0.64 / 0.25, 1e-9);
  // One scale per gap, each in (0, 1].
  for (const std::vector<double>& bad : {std::vector<double>{1.0}, {1.0, 0.0}, {1.5, 1.0}, {NAN, 1.0}}) {
    stop.gap_accel_scale = bad;
    EXPECT_THROW(region_path(three, stop), std::invalid_argument);
  }
}

// A tight pass end (the nozzle leans there with room for the run-on only: Pass::tight_*) is
// turned without running on: the nozzle stops within v^2 / a of the end, creeps across to the
// next pass (tracked, not a joint move: the pump is not blocked there) and starts from rest, the
// whole join lasting the pump's off spell (min_turn_s), at most the turn acceleration along it. The
// other end keeps its turn-around, which runs on past the ends by its runs and more.
TEST(RegionPath, ATightEndIsTurnedWithinItsStopAndTheTurnLastsThePumpSpell) {
  auto passes = axial_region(3, 1.0, 0.2, 0.0, 1.0, {0.2});  // x = 0 -> 1, 1 -> 0, 0 -> 1
  passes[0].tight_end = passes[1].tight_start = true;          // the end at x = 1
  RegionPathOptions o = leads(0.1, 0.1, 0.1);
  o.stop_accel_mps2 = 2.0;
  o.turn_speed_mps = 0.5;
  o.turn_accel_mps2 = 1.0;
  o.min_turn_s = 2.1;
  const CartesianPath path = region_path(passes, o);
  std::vector<PieceMotion> motions;
  int turns = 0;
  for (const auto& p : path.pieces()) {
    if (p.kind == SegmentKind::Turn) ++turns;
    if (p.motion != PieceMotion::ByKind) motions.push_back(p.motion);
  }
  EXPECT_EQ(turns, 1);  // at x = 0
  EXPECT_EQ(motions, (std::vector<PieceMotion>{PieceMotion::StopAtEnd, PieceMotion::Creep, PieceMotion::StartFromRest}));
  TimingParams prm;
  prm.turn_speed_mps = 0.5;
  prm.turn_accel_mps2 = 1.0;
  prm.min_turn_s = 2.1;
  const CartesianSamples cs = sample_path(path, region_profile(path, prm), 1000.0);
  double x_hi = -1e9, x_lo = 1e9, creep_accel = 0.0;
  std::vector<double> gaps;
  double last_end = -1.0;
  int last_pass = -1;
  for (std::size_t i = 0; i < cs.t_s.size(); ++i) {
    if (cs.kind[i] != static_cast<char>(SegmentKind::Lead)) {
      x_hi = std::max(x_hi, cs.nozzle[i].position_m.x());
      x_lo = std::min(x_lo, cs.nozzle[i].position_m.x());
    }
    double local = 0.0;
    if (path.pieces()[path.locate(cs.s_m[i], local)].motion == PieceMotion::Creep)
      creep_accel = std::max(creep_accel, std::abs(cs.tangential_accel_mps2[i]));
    if (cs.kind[i] != static_cast<char>(SegmentKind::Pass)) continue;
    if (last_pass >= 0 && cs.pass_index[i] != last_pass) gaps.push_back(cs.t_s[i] - last_end);
    last_pass = cs.pass_index[i];
    last_end = cs.t_s[i];
  }
  // The stop from 0.2 m/s at 2 m/s^2 needs 0.02 m; the turn at x = 0 runs on 0.1 m and more.
  EXPECT_LT(x_hi, 1.0 + 0.02 + 1e-6);
  EXPECT_GT(x_hi, 1.0 + 0.02 - 1e-3);
  EXPECT_LT(x_lo, -0.1);
  ASSERT_EQ(gaps.size(), 2u);
  EXPECT_NEAR(gaps[0], 2.1, 2e-3);
  EXPECT_GT(creep_accel, 0.0);
  EXPECT_LT(creep_accel, 1.0 + 1e-6);
  // Without the pump's spell the creep runs as fast as the turn acceleration allows: its peak.
  TimingParams fast = prm;
  fast.min_turn_s = 0.0;
  const CartesianSamples cf = sample_path(path, region_profile(path, fast), 1000.0);
  double peak = 0.0;
  for (std::size_t i = 0; i < cf.t_s.size(); ++i) {
    double local = 0.0;
    if (path.pieces()[path.locate(cf.s_m[i], local)].motion == PieceMotion::Creep)
      peak = std::max(peak, std::abs(cf.tangential_accel_mps2[i]));
  }
  EXPECT_GT(peak, 0.95);
  EXPECT_LT(peak, 1.0 + 1e-3);
  // The pump runs over the tight turn as over any turn: nothing is blocked, and it switches off
  // over it (three spells, the off spells at least min_off_s).
  Config c;
  c.timing.turn_run_m = 0.1;
  for (auto& p : passes) p.speed_mps = 0.2;
  const RegionSpray spray = region_spray(passes, c);
  EXPECT_TRUE(std::none_of(spray.blocked.begin(), spray.blocked.end(), [](char b) { return b != 0; }));
  EXPECT_EQ(spray.flow.on_s.size(), 3u);
  EXPECT_GE(spray.flow.shortest_off_s(), c.flow.min_off_s - 1e-9);
  // Without the tight flags both ends turn around.
  passes[0].tight_end = passes[1].tight_start = false;
  int plain_turns = 0;
  const CartesianPath plain = region_path(passes, o);
  for (const auto& p : plain.pieces()) plain_turns += p.kind == SegmentKind::Turn;
  EXPECT_EQ(plain_turns, 2);
}

// A leaning nozzle's axis turns along its passes (the lean fades over the bay). The runs, turns,
// stop-and-go runs and leads carry that turn down to 0 over at most 0.1 m instead of holding the
// axis (the turn stepped from 0.05 deg per 50 Hz sample to 0 within one sample there: joint
// accelerations of 3-4x their limits in the face scene); the path's positions are those of square
// axes.
TEST(RegionPath, JoinsAndLeadsCarryTheAxisTurnOfThePassesWithoutAStep) {
  Config cfg;
  const double rate = 0.3;  // rad per metre of pass, about x: sideways, no pass end leans ahead
  auto tilted = [&](double z, bool back) {
    Pass p = line_along_x(z, 0.25);
    for (auto& w : p.waypoints) {
      const double a = rate * w.position_m.x();
      w.axis = Eigen::Vector3d(0.0, std::sin(a), std::cos(a));
    }
    if (back) std::reverse(p.waypoints.begin(), p.waypoints.end());
    return p;
  };
  // Serpentine (turns) and same-direction lines (stop-and-go), each with leads.
  for (const bool serpentine : {true, false}) {
    const std::vector<Pass> passes = {tilted(4.6, false), tilted(4.8, serpentine), tilted(5.0, false)};
    const CartesianPath path = timing_region_path(passes, 0.2, 0.2, cfg.timing);
    std::vector<Pass> square = passes;
    for (auto& p : square)
      for (auto& w : p.waypoints) w.axis = Eigen::Vector3d::UnitZ();
    const CartesianPath plain = timing_region_path(square, 0.2, 0.2, cfg.timing);
    ASSERT_NEAR(path.length_m(), plain.length_m(), 1e-9) << serpentine;
    const double h = 0.001;
    double prev_rate = 0.0, worst_step = 0.0, peak_rate = 0.0;
    bool prev_middle = false;
    int stops = 0, off_positions = 0;
    for (const auto& piece : path.pieces()) stops += piece.motion == PieceMotion::StopAtEnd;
    EXPECT_EQ(stops, serpentine ? 0 : 2);
    for (double s = 0.0; s + h <= path.length_m(); s += h) {
      const NozzlePose a = path.pose_at(s), b = path.pose_at(s + h);
      off_positions += (a.position_m - plain.pose_at(s).position_m).norm() > 1e-9;
      const double r = std::acos(std::clamp(a.axis.normalized().dot(b.axis.normalized()), -1.0, 1.0)) / h;
      // (A stop-and-go middle goes from rest to rest: its turn in time starts and ends at 0.)
      double local = 0.0;
      const bool middle = path.pieces()[path.locate(s, local)].motion == PieceMotion::RestToRest ||
                          path.pieces()[path.locate(s + h, local)].motion == PieceMotion::RestToRest;
      if (s > 0.0 && !middle && !prev_middle) worst_step = std::max(worst_step, std::abs(r - prev_rate));
      prev_middle = middle;
      peak_rate = std::max(peak_rate, r);
      prev_rate = r;
    }
    // The passes turn at 0.3 rad/m; nothing steps by more than a tenth of that per millimetre.
    EXPECT_NEAR(peak_rate, rate, 0.5 * rate) << serpentine;
    EXPECT_LT(worst_step, 0.1 * rate) << serpentine;
    EXPECT_EQ(off_positions, 0) << serpentine;
    // The runs' far ends turn no more: the lead-in starts and the lead-out ends with rate 0.
    const double end = path.length_m();
    for (const auto& [s0, s1] : {std::pair{0.0, 0.002}, std::pair{end - 0.002, end}}) {
      const NozzlePose l0 = path.pose_at(s0), l1 = path.pose_at(s1);
      EXPECT_LT(std::acos(std::min(1.0, l0.axis.dot(l1.axis))) / 0.002, 0.02 * rate) << serpentine << " " << s0;
    }
  }
  // A long lead (1 m: the timing swarm's, or an eased one) carries the turn over its last 0.1 m
  // only: its start is turned rate x 0.05 m from the pass's, and the axis is held before that.
  {
    const std::vector<Pass> passes = {tilted(4.6, false), tilted(4.8, true)};
    const CartesianPath long_leads = timing_region_path(passes, 1.0, 1.0, cfg.timing);
    const Eigen::Vector3d first = passes[0].waypoints.front().axis;
    EXPECT_NEAR(std::acos(std::min(1.0, long_leads.pose_at(0.0).axis.dot(first))), rate * 0.05, 2e-3);
    EXPECT_LT((long_leads.pose_at(0.0).axis - long_leads.pose_at(0.85).axis).norm(), 1e-9);
  }
  // An axis turning at 0.05 rad/m (a rough wall's square passes turn at up to 0.03) keeps its
  // runs and leads as before: straight, the axis held.
  auto slow = [&](double z) {
    Pass p = line_along_x(z, 0.25);
    for (auto& w : p.waypoints) w.axis = Eigen::Vector3d(0.0, std::sin(0.05 * w.position_m.x()), std::cos(0.05 * w.position_m.x()));
    return p;
  };
  const CartesianPath held = timing_region_path({slow(4.6), slow(4.8)}, 0.2, 0.2, cfg.timing);
  for (const auto& piece : held.pieces())
    if (piece.kind == SegmentKind::Lead || piece.motion == PieceMotion::StopAtEnd || piece.motion == PieceMotion::StartFromRest) {
      EXPECT_EQ(piece.poses.size(), 2u);
      EXPECT_LT((piece.poses.front().axis - piece.poses.back().axis).norm(), 1e-12);
    }
}

// What the planner deposits with: the region's passes timed as time_plan times them, with the
// pump's flow over the spraying flags.
TEST(RegionSpray, IdealPumpSpraysExactlyThePassTimes) {
  Config cfg;
  cfg.flow.ramp_s = 0.0, cfg.flow.min_on_s = 0.0, cfg.flow.min_off_s = 0.0;
  const std::vector<Pass> passes = axial_region(3, 1.2, 0.3, 0.0, 1.0, {0.25, 0.4, 0.3});
  const RegionSpray spray = region_spray(passes, cfg);
  double pass_time = 0.0;
  for (const auto& p : passes) pass_time += p.duration_s();
  const double dt = 1.0 / cfg.timing.trajectory_rate_hz;
  // The flags ask for the passes' time, up to one sample at each switch.
  EXPECT_NEAR(spray.flow.commanded_on_s, pass_time, 6 * dt);
  EXPECT_DOUBLE_EQ(spray.flow.on_time_s(), spray.flow.commanded_on_s);
  double dwell = 0.0;
  for (double d : spray.dwell_s) dwell += d;
  EXPECT_NEAR(dwell, spray.flow.on_time_s(), 1e-9);
  // Leads at the config's lengths or longer (lead_lengths), turns: the region lasts longer.
  const auto [lead_in, lead_out] = lead_lengths(passes, TimingParams::from_config(cfg.timing),
                                                cfg.timing.nozzle_max_accel_mps2, cfg.timing.nozzle_max_accel_mps2);
  EXPECT_GE(lead_in, cfg.timing.start_length_m);
  EXPECT_GE(lead_out, cfg.timing.end_length_m);
  EXPECT_GT(spray.duration_s(), pass_time + (lead_in + lead_out) / 0.4);
  ASSERT_EQ(spray.nozzle.size(), spray.t_s.size());
  // Spraying samples lie on the passes: at their radius from the axis.
  for (std::size_t i = 0; i < spray.t_s.size(); ++i) {
    if (spray.dwell_s[i] > 0) {
      EXPECT_NEAR(spray.nozzle[i].position_m.tail<2>().norm(), 4.6, 1e-6);
    }
  }
}

TEST(RegionSpray, PumpSpellsAndRampsKeepTheVolume) {
  Config cfg;  // default pump: 2 s ramps and minimum spells
  const std::vector<Pass> passes = axial_region(2, 1.5, 0.15, 0.0, 1.0, {0.5});
  const RegionSpray spray = region_spray(passes, cfg);
  EXPECT_GE(spray.flow.shortest_on_s(), cfg.flow.min_on_s - 1e-9);
  double dwell = 0.0;
  int ramping = 0;
  const double dt = 1.0 / cfg.timing.trajectory_rate_hz;
  for (std::size_t i = 0; i + 1 < spray.dwell_s.size(); ++i) {
    dwell += spray.dwell_s[i];
    if (i > 0 && spray.dwell_s[i] > 1e-9 && spray.dwell_s[i] < 0.99 * dt) ++ramping;
  }
  dwell += spray.dwell_s.back();
  // Ramps lay what steps lay: the flow-on time is what the flags ask for plus what the pump adds.
  EXPECT_NEAR(dwell, spray.flow.on_time_s(), 1e-9);
  EXPECT_NEAR(spray.flow.on_time_s(), spray.flow.commanded_on_s + spray.flow.bridged_s + spray.flow.extended_s - spray.flow.dropped_s - spray.flow.trimmed_s, 1e-9);
  // Each switch ramps over ramp_s: about ramp_s * rate samples at part flow per switch.
  EXPECT_GE(ramping, spray.flow.switches() * static_cast<int>(0.9 * cfg.flow.ramp_s / dt));
}

// The leads last at least timing.min_lead_s at any pass speed (lead_lengths' closed forms), so the
// pump's ramps run on them: the flow is 0 at the region's first and last samples (the transits
// around it are dry) and no commanded flow is cut at its ends (dropped_s 0), also for a fast
// pass whose leads the acceleration limit and the config's 0.1 m alone make 0.67 s long.
TEST(RegionSpray, LeadsCarryThePumpRampsWithinTheRegion) {
  Config cfg;  // default pump: 2 s ramps and spells; min_lead_s = 1 s
  ASSERT_GE(cfg.timing.min_lead_s, 0.5 * cfg.flow.ramp_s);
  for (double v : {0.05, 0.2, 0.5}) {
    const std::vector<Pass> passes = axial_region(2, 1.2, 0.3, 0.0, 1.0, {v});
    const RegionSpray spray = region_spray(passes, cfg);
    // Lead durations by the profile's closed forms; the spells below check them on the samples.
    const TimingParams params = TimingParams::from_config(cfg.timing);
    const auto [lead_in, lead_out] =
        lead_lengths(passes, params, cfg.timing.nozzle_max_accel_mps2, cfg.timing.nozzle_max_accel_mps2);
    const double t_in = 2.0 * lead_in / (v * (2.0 - params.k1)), t_out = 2.0 * lead_out / (v * (1.0 + params.k2));
    EXPECT_GE(t_in, cfg.timing.min_lead_s - 1e-9) << v;
    EXPECT_GE(t_out, cfg.timing.min_lead_s - 1e-9) << v;
    ASSERT_FALSE(spray.flow.on_s.empty()) << v;
    const double dt = 1.0 / cfg.timing.trajectory_rate_hz;
    // The first spell starts at the pass's start, one lead-in after the region's; the ramp fits.
    EXPECT_NEAR(spray.flow.on_s.front(), t_in, 2 * dt) << v;
    EXPECT_NEAR(spray.t_s.back() - spray.flow.off_s.back(), t_out, 2 * dt) << v;
    EXPECT_NEAR(spray.flow.dropped_s, 0.0, 1e-9) << v;
    EXPECT_DOUBLE_EQ(spray.flow.flow_at(spray.t_s.front()), 0.0) << v;
    EXPECT_DOUBLE_EQ(spray.flow.flow_at(spray.t_s.back()), 0.0) << v;
  }
  // Without the minimum a fast pass's leads are shorter than the half ramp: its spell's ends are
  // cut where the ramps would reach the transits.
  cfg.timing.min_lead_s = 0.0;
  const RegionSpray short_leads = region_spray(axial_region(2, 1.2, 0.3, 0.0, 1.0, {0.2}), cfg);
  EXPECT_GT(short_leads.flow.dropped_s, 0.1);
}

// The profile of a region's pieces (library-internal, timing/detail.hpp).
#include "../../cpp/src/timing/detail.hpp"

TEST(RegionProfile, AnEasedTurnSlowsItsArcEvenBelowTheCentripetalCap) {
  // Passes at 0.1 m/s joined by a half circle of radius 0.1 m: the cap sqrt(0.5 x 0.1) = 0.22 m/s
  // lies above the pass speed, so the arc runs at the pass speed. A gap eased to a quarter of its
  // accelerations (time_region_within_limits) must slow the arc by sqrt(1/4), so its centripetal
  // acceleration v^2 / r eases with the scale too (it did not: a graded demo kept a turn 1.1 %
  // over a joint acceleration limit through every easing).
  using namespace shotcrete;
  using timing_detail::PieceSpec;
  TimingConfig slow_turns;  // the arc at the pass speed, under the centripetal cap
  slow_turns.turn_speed_mps = 0.0;
  slow_turns.turn_accel_mps2 = 0.0;
  const TimingParams params = TimingParams::from_config(slow_turns);
  auto arc_min_speed = [&](double scale) {
    const double r = 0.1, v = 0.1;
    std::vector<PieceSpec> specs = {
        {SegmentKind::Lead, 0.3, v, v, {}, {}, PieceMotion::ByKind, 1.0},
        {SegmentKind::Pass, 1.0, v, v, {}, {}, PieceMotion::ByKind, 1.0},
        {SegmentKind::Turn, M_PI * r, v, v, {}, {}, PieceMotion::ByKind, scale},
        {SegmentKind::Pass, 1.0, v, v, {}, {}, PieceMotion::ByKind, 1.0},
        {SegmentKind::Lead, 0.3, v, v, {}, {}, PieceMotion::ByKind, 1.0}};
    const SpeedProfile prof = timing_detail::profile_from_specs(specs, params);
    // Lowest speed between the end of the first pass and the start of the second (the arc).
    double lo = 1e9;
    const double s0 = 1.3, s1 = 1.3 + M_PI * r;
    for (double s = s0 + 1e-3; s < s1 - 1e-3; s += 1e-3) lo = std::min(lo, prof.at(prof.time_at_distance(s)).v_mps);
    return lo;
  };
  EXPECT_NEAR(arc_min_speed(1.0), 0.1, 1e-9);
  EXPECT_NEAR(arc_min_speed(0.25), 0.05, 1e-6);
}
