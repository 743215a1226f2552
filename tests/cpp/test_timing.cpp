// Motion timing: the paper's start/end profiles against their closed forms integrated numerically,
// turn-around geometry, quintic boundary conditions, sampling/dwells, the swarm on functions with a
// known minimum, joint-space transits and the timed trajectory of real passes on the robot.
#include <gtest/gtest.h>

#include <cmath>
#include <algorithm>
#include <functional>

#include "shotcrete/pipeline/arm_plan.hpp"
#include "shotcrete/robot/robot.hpp"
#include "shotcrete/timing/timing.hpp"

using namespace shotcrete;

namespace {

constexpr double kPi = 3.14159265358979323846;

// Composite Simpson on [a, b] with n (even) intervals.
double simpson(const std::function<double(double)>& f, double a, double b, int n = 2000) {
  const double h = (b - a) / n;
  double s = f(a) + f(b);
  for (int i = 1; i < n; ++i) s += (i % 2 ? 4.0 : 2.0) * f(a + i * h);
  return s * h / 3.0;
}

// The paper's formulas written out literally (design 7b), independent of the implementation.
double paper_start_v(double t, double s_start, double vmax, double k1) {
  const double Ts = 2.0 * s_start / (vmax * (2.0 - k1)), t1 = k1 * Ts;
  if (t >= t1) return vmax;
  const double m = 2.0 * kPi * t / t1;
  return vmax / (2.0 * kPi) * (m - std::sin(m));
}
double paper_end_v(double t, double s_end, double vmax, double k2) {
  const double Te = 2.0 * s_end / (vmax * (1.0 + k2)), t2 = k2 * Te;
  if (t <= t2) return vmax;
  const double m = 2.0 * kPi * (Te - t) / (Te - t2);
  return vmax / (2.0 * kPi) * (m - std::sin(m));
}

// Axial passes on a nozzle cylinder of radius rn (wall 5.6 m at 1 m standoff), serpentine.
std::vector<Pass> axial_region(int n, double length, double wall_spacing, double x0, double theta0,
                               const std::vector<double>& speeds, double rn = 4.6, double R = 5.6) {
  std::vector<Pass> passes;
  for (int i = 0; i < n; ++i) {
    const double th = theta0 + i * wall_spacing / R;
    Pass p;
    const int m = static_cast<int>(std::round(length / 0.01));
    for (int k = 0; k <= m; ++k) {
      const double f = static_cast<double>(k) / m;
      const double x = x0 + (i % 2 == 0 ? f : 1.0 - f) * length;
      NozzlePose w;
      w.position_m = Eigen::Vector3d(x, rn * std::cos(th), rn * std::sin(th));
      w.axis = Eigen::Vector3d(0, std::cos(th), std::sin(th));
      p.waypoints.push_back(w);
    }
    p.speed_mps = speeds[static_cast<std::size_t>(i) % speeds.size()];
    p.length_m = length;
    passes.push_back(p);
  }
  return passes;
}

}  // namespace

TEST(Profiles, CycloidStartMatchesPaperAndCoversStartLength) {
  for (double k1 : {0.2, 0.5, 0.8, 1.0}) {
    const double s = 0.15, v = 0.35;
    const SpeedProfile p = cycloid_start(s, v, k1);
    const double Ts = 2.0 * s / (v * (2.0 - k1));
    EXPECT_NEAR(p.duration_s(), Ts, 1e-12);
    // Distance of the paper's v(t) integrated numerically equals s_start: Ts formula is consistent.
    const double dist = simpson([&](double t) { return paper_start_v(t, s, v, k1); }, 0.0, k1 * Ts) +
                        v * (1.0 - k1) * Ts;
    EXPECT_NEAR(dist, s, 1e-9) << "k1 " << k1;
    EXPECT_NEAR(p.length_m(), s, 1e-12);
    for (int i = 0; i <= 200; ++i) {
      const double t = Ts * i / 200.0;
      const auto st = p.at(t);
      ASSERT_NEAR(st.v_mps, paper_start_v(t, s, v, k1), 1e-12) << "t " << t;
      // s(t) against the numerical integral of the paper's v(t).
      const double ref = simpson([&](double x) { return paper_start_v(x, s, v, k1); }, 0.0, t, 400);
      ASSERT_NEAR(st.s_m, ref, 1e-6) << "t " << t;
    }
    // Acceleration starts and ends at zero (no jumps), velocity continuous at t1.
    const double t1 = k1 * Ts;
    EXPECT_NEAR(p.at(0.0).a_mps2, 0.0, 1e-12);
    EXPECT_NEAR(p.at(t1 - 1e-9).a_mps2, 0.0, 1e-5);
    EXPECT_NEAR(p.at(t1 - 1e-9).v_mps, v, 1e-8);
    EXPECT_NEAR(p.at(t1 + 1e-9).v_mps, v, 1e-12);
    // Peak acceleration of the cycloid is 2 v / t1 at t1 / 2.
    EXPECT_NEAR(p.at(0.5 * t1).a_mps2, 2.0 * v / t1, 1e-9);
  }
}

TEST(Profiles, CycloidEndMatchesPaperAndCoversEndLength) {
  for (double k2 : {0.0, 0.3, 0.5, 0.9}) {
    const double s = 0.2, v = 0.25;
    const SpeedProfile p = cycloid_end(s, v, k2);
    const double Te = 2.0 * s / (v * (1.0 + k2));
    EXPECT_NEAR(p.duration_s(), Te, 1e-12);
    const double dist = v * k2 * Te + simpson([&](double t) { return paper_end_v(t, s, v, k2); }, k2 * Te, Te);
    EXPECT_NEAR(dist, s, 1e-9) << "k2 " << k2;
    for (int i = 0; i <= 200; ++i) {
      const double t = Te * i / 200.0;
      ASSERT_NEAR(p.at(t).v_mps, paper_end_v(t, s, v, k2), 1e-12) << "t " << t;
    }
    EXPECT_NEAR(p.at(Te).v_mps, 0.0, 1e-12);
    EXPECT_NEAR(p.at(Te).a_mps2, 0.0, 1e-12);
    EXPECT_NEAR(p.at(k2 * Te + 1e-9).a_mps2, 0.0, 1e-5);
    EXPECT_NEAR(p.at(Te).s_m, s, 1e-12);
  }
}

TEST(Profiles, DerivativesAreConsistent) {
  // v = ds/dt, a = dv/dt, j = da/dt by central differences on a composite profile.
  SpeedProfile p = cycloid_start(0.1, 0.3, 0.6);
  p.append(SpeedPiece{0.3, 0.1, 0.8, SpeedShape::Cycloid});
  p.append(rest_to_rest(0.5, 0.4, 0.7, SpeedShape::Quintic));
  const double h = 1e-5;
  for (int i = 1; i < 400; ++i) {
    const double t = p.duration_s() * i / 400.0;
    const auto a = p.at(t - h), b = p.at(t + h), c = p.at(t);
    ASSERT_NEAR((b.s_m - a.s_m) / (2 * h), c.v_mps, 1e-6) << t;
    ASSERT_NEAR((b.v_mps - a.v_mps) / (2 * h), c.a_mps2, 1e-4) << t;
  }
  // Jerk inside one piece (the jerk of a cycloid jumps at piece ends by design).
  const SpeedPiece q{0.0, 0.5, 1.3, SpeedShape::Quintic};
  for (double t : {0.1, 0.4, 0.77, 1.2})
    EXPECT_NEAR((q.accel_at(t + h) - q.accel_at(t - h)) / (2 * h), q.jerk_at(t), 1e-4);
  // Bisection for the time of a distance.
  for (double s : {0.0, 0.05, 0.3, p.length_m()}) EXPECT_NEAR(p.at(p.time_at_distance(s)).s_m, s, 1e-9);
}

TEST(Profiles, QuinticBoundaryConditions) {
  const double L = 1.0, v = 0.3, ta = 0.9;
  const SpeedProfile p = rest_to_rest(L, v, ta, SpeedShape::Quintic);
  ASSERT_EQ(p.pieces().size(), 3u);
  const double T = p.duration_s();
  EXPECT_NEAR(T, ta + (L - v * ta) / v + ta, 1e-12);
  // Start and end at rest with zero acceleration and zero jerk; cruise reached with zero a and j.
  for (double t : {0.0, T}) {
    const auto st = p.at(t);
    EXPECT_NEAR(st.v_mps, 0.0, 1e-12);
    EXPECT_NEAR(st.a_mps2, 0.0, 1e-12);
    EXPECT_NEAR(st.j_mps3, 0.0, 1e-12);
  }
  const SpeedPiece& acc = p.pieces()[0];
  EXPECT_NEAR(acc.speed_at(ta), v, 1e-12);
  EXPECT_NEAR(acc.accel_at(ta), 0.0, 1e-12);
  EXPECT_NEAR(acc.jerk_at(ta), 0.0, 1e-12);
  EXPECT_NEAR(acc.jerk_at(0.0), 0.0, 1e-12);
  // v(t) = v (10 tau^3 - 15 tau^4 + 6 tau^5): independent closed form, peak accel 1.875 v / ta.
  for (double tau : {0.1, 0.37, 0.5, 0.81}) {
    EXPECT_NEAR(acc.speed_at(tau * ta), v * (10 * std::pow(tau, 3) - 15 * std::pow(tau, 4) + 6 * std::pow(tau, 5)), 1e-12);
  }
  EXPECT_NEAR(acc.peak_accel_mps2(), 1.875 * v / ta, 1e-12);
  EXPECT_NEAR(acc.accel_at(0.5 * ta), 1.875 * v / ta, 1e-12);
  EXPECT_NEAR(simpson([&](double t) { return p.at(t).v_mps; }, 0.0, T, 4000), L, 1e-7);
  // Too short to reach v: the peak drops, length kept.
  const SpeedProfile s = rest_to_rest(0.1, 0.3, 0.9, SpeedShape::Quintic);
  EXPECT_NEAR(s.length_m(), 0.1, 1e-12);
  EXPECT_NEAR(s.at(0.9).v_mps, 0.1 / 0.9, 1e-12);
  EXPECT_THROW(rest_to_rest(1.0, 0.0, 1.0, SpeedShape::Quintic), std::invalid_argument);
  EXPECT_THROW(cycloid_start(0.0, 0.3, 0.5), std::invalid_argument);
  EXPECT_THROW(cycloid_end(0.1, 0.3, 1.0), std::invalid_argument);
}

TEST(Geometry, TurnAroundDiameterIsSpacingAndTangentsContinuous) {
  // Pass a ends at x = 1.0 going +x; pass b starts at x = 1.15 going -x, 0.2 m across (in y).
  NozzlePose ea, sb;
  ea.position_m = {1.0, 0.0, 2.0};
  sb.position_m = {1.15, 0.2, 2.0};
  ea.axis = sb.axis = Eigen::Vector3d(0, 0, 1);
  const auto pieces = turn_around(ea, Eigen::Vector3d::UnitX(), sb, 0.3, 0.2, false);
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
  const auto p2 = turn_around(ea, Eigen::Vector3d::UnitX(), sb, 0.3, 0.3, false);
  ASSERT_EQ(p2.size(), 2u);
  EXPECT_TRUE(p2[0].is_arc);
  EXPECT_NEAR(p2[1].length_m(), 0.1, 1e-12);
  EXPECT_NEAR((p2[1].tangent_at(0.05) - Eigen::Vector3d(-1, 0, 0)).norm(), 0.0, 1e-12);
  // With runs, both sides get a link whatever the offset, and the pieces stay contiguous.
  for (double xb : {0.7, 0.95, 1.05, 1.4}) {
    sb.position_m = {xb, 0.2, 2.0};
    const auto p3 = turn_around(ea, Eigen::Vector3d::UnitX(), sb, 0.3, 0.3, false, 0.1);
    ASSERT_EQ(p3.size(), 3u) << xb;
    EXPECT_NEAR((p3[0].pose_at(0).position_m - ea.position_m).norm(), 0.0, 1e-12);
    for (int k = 0; k < 2; ++k)
      EXPECT_NEAR((p3[k].pose_at(p3[k].length_m()).position_m - p3[k + 1].pose_at(0).position_m).norm(), 0.0, 1e-12) << xb;
    EXPECT_NEAR((p3[2].pose_at(p3[2].length_m()).position_m - sb.position_m).norm(), 0.0, 1e-12) << xb;
  }
  sb.position_m = {1.2, 0.0, 2.0};
  EXPECT_THROW(turn_around(ea, Eigen::Vector3d::UnitX(), sb, 0.3, 0.3, false), std::invalid_argument);
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
  const auto pieces = turn_around(ea, Eigen::Vector3d::UnitX(), sb, 0.3, 0.2, false, 0.1, 0.5, db);
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
  const auto straight = turn_around(ea, Eigen::Vector3d::UnitX(), sb, 0.3, 0.2, false, 0.1, 0.5);
  EXPECT_EQ(straight[2].poses.size(), 2u);
}

TEST(Region, TurnRunsSizedForTheSpeedChange) {
  // Passes at 0.8 m/s, 0.2 m apart: the arc (r = 0.1 m) is capped at sqrt(0.5 * 0.1) = 0.224 m/s
  // and the runs must bring 0.8 m/s down to it at 0.5 m/s^2: (0.64 - 0.05) / 0.5 = 1.18 m.
  const auto passes = axial_region(2, 1.2, 0.2, 0.0, 1.2, {0.8}, 4.6, 4.6 + 1e-9);
  const double a = 0.5;
  const CartesianPath path = region_path(passes, 0.1, 0.1, false, 0, 0.1, 0.0, 0.0, a);
  TimingParams prm = TimingParams::from_config(TimingConfig{});
  prm.speed_change_accel_mps2 = a;
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
  const CartesianPath eased = region_path(passes, 0.1, 0.1, false, 0, 0.1, 0.0, 0.0, a, {0.5});
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
  const CartesianPath fixed = region_path(passes, 0.1, 0.1, false, 0, 0.1);
  for (const auto& p : fixed.pieces()) {
    if (p.kind == SegmentKind::Link) {
      EXPECT_NEAR(p.length_m(), 0.1, 1e-9);
    }
  }
}

TEST(Region, SerpentineNeverStopsAndKeepsPassSpeeds) {
  const auto passes = axial_region(6, 1.2, 0.2, 0.0, 1.2, {0.2, 0.3, 0.25});
  TimingParams prm;
  prm.k1 = 0.6;
  prm.k2 = 0.4;
  prm.start_length_m = prm.end_length_m = 0.12;
  const CartesianPath path = region_path(passes, prm.start_length_m, prm.end_length_m, false);
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
    const CartesianPath with_runs = region_path(passes, prm.start_length_m, prm.end_length_m, false, 0, 0.1);
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
  const CartesianPath path = region_path(passes, 0.1, 0.1, false, 0, 0.15);
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

TEST(Region, PassSpeedProfileKeptWithSmoothChanges) {
  // One pass of 1 m: waypoints 0..50 at 0.2 m/s, 51..100 at 0.4 m/s (optimal-mode speed profile).
  auto passes = axial_region(1, 1.0, 0.2, 0.0, 1.0, {0.3});
  Pass& p = passes[0];
  for (std::size_t k = 0; k < p.waypoints.size(); ++k) p.speed_profile_mps.push_back(k <= 50 ? 0.2 : 0.4);
  TimingParams prm;
  prm.speed_change_accel_mps2 = 0.5;
  const CartesianPath path = region_path(passes, 0.1, 0.1, false);
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
  EXPECT_THROW(region_path(passes, 0.1, 0.1, false), std::invalid_argument);
}

TEST(Region, NozzleCheckSeesCentripetalAcceleration) {
  const auto passes = axial_region(2, 1.0, 0.2, 0.0, 1.0, {0.4});
  TimingParams prm;
  prm.k1 = 1.0;
  prm.k2 = 0.0;
  prm.start_length_m = prm.end_length_m = 0.5;  // gentle start/stop: the arc dominates
  prm.speed_change_accel_mps2 = 10.0;           // no arc speed cap
  const CartesianPath path = region_path(passes, 0.5, 0.5, false);
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
  const CartesianPath path = region_path(passes, prm.start_length_m, prm.end_length_m, false);
  EXPECT_LT(region_profile(path, prm).duration_s(), b.profile.duration_s());
}

TEST(Joint, QuinticMinDurationHitsTheBindingLimit) {
  Eigen::VectorXd q0(3), q1(3), vl(3), al(3);
  q0 << 0.0, 1.0, -0.5;
  q1 << 1.2, 0.8, 0.5;
  vl << 0.5, 1.0, 2.0;
  al << 2.0, 1.0, 0.2;
  const double T = quintic_min_duration(q0, q1, vl, al);
  EXPECT_NEAR(T, std::max({1.875 * 1.2 / 0.5, std::sqrt(10.0 / std::sqrt(3.0) * 1.0 / 0.2)}), 1e-12);
  double rv = 0.0, ra = 0.0;
  Eigen::VectorXd q, qd, qdd;
  for (int i = 0; i <= 10000; ++i) {
    quintic_joint(q0, q1, T, T * i / 10000.0, q, qd, qdd);
    rv = std::max(rv, qd.cwiseAbs().cwiseQuotient(vl).maxCoeff());
    ra = std::max(ra, qdd.cwiseAbs().cwiseQuotient(al).maxCoeff());
  }
  EXPECT_LE(rv, 1.0 + 1e-9);
  EXPECT_LE(ra, 1.0 + 1e-9);
  EXPECT_NEAR(std::max(rv, ra), 1.0, 1e-6);  // minimum: one limit is reached
  quintic_joint(q0, q1, T, T, q, qd, qdd);
  EXPECT_NEAR((q - q1).norm(), 0.0, 1e-12);
  EXPECT_NEAR(qd.norm() + qdd.norm(), 0.0, 1e-12);
}

TEST(Joint, TrackingPullsAJointBackFromItsLimit) {
  // From the ready posture, push the nozzle 3 m along its own axis (or 2 m straight up): the arm
  // telescope runs out to its limit unless the null-space drift hands the extension over to the
  // other joints in time. A fixed drift cap of 0.05 range/m overran it by 45 mm / 15 mm.
  const Robot robot = Robot::load(RobotConfig{});
  const Eigen::VectorXd q0 = robot.neutral();
  const Eigen::Isometry3d T0 = robot.fk(q0);
  for (const auto& [dir, length] : {std::pair<Eigen::Vector3d, double>{T0.linear().col(2), 3.0},
                                    std::pair<Eigen::Vector3d, double>{Eigen::Vector3d::UnitZ(), 2.0}}) {
    std::vector<NozzlePose> poses;
    for (double s = 0.0; s <= length + 1e-9; s += 0.005) {
      NozzlePose p;
      p.position_m = T0.translation() + s * dir;
      p.axis = T0.linear().col(2);
      poses.push_back(p);
    }
    double em = 0.0, ea = 0.0;
    const auto q = track_joint_path(robot, poses, q0, 0.02, &em, &ea);
    EXPECT_LT(em, 1e-9);
    EXPECT_LT(ea, 1e-9);
    for (std::size_t k = 0; k < q.size(); ++k) ASSERT_TRUE(robot.within_limits(q[k])) << "step " << k << " of " << length;
    // Still a smooth function of the path: no joint jumps between 5 mm steps.
    for (std::size_t k = 1; k < q.size(); ++k) ASSERT_LT((q[k] - q[k - 1]).cwiseAbs().maxCoeff(), 0.02) << k;
  }
}

TEST(Pso, FindsKnownMinima) {
  PsoOptions o;
  o.particles = 15;
  o.iterations = 200;
  o.seed = 7;
  // Shifted sphere in 5-D, minimum 0 at c.
  Eigen::VectorXd c(5), lo(5), hi(5);
  c << 0.3, -1.2, 2.5, 0.0, 1.7;
  lo.setConstant(-5.0);
  hi.setConstant(5.0);
  auto sphere = [&](const Eigen::VectorXd& x) { return (x - c).squaredNorm(); };
  const PsoResult r = pso_minimize(sphere, lo, hi, o);
  EXPECT_LT((r.best_x - c).norm(), 1e-3);
  EXPECT_LT(r.best_f, 1e-6);
  EXPECT_EQ(r.evaluations, 15 * 201);
  for (std::size_t i = 1; i < r.best_history.size(); ++i) EXPECT_LE(r.best_history[i], r.best_history[i - 1]);
  for (double b : r.success_history) {
    EXPECT_GE(b, 0.0);
    EXPECT_LE(b, 1.0);
  }
  // Deterministic for a seed.
  const PsoResult r2 = pso_minimize(sphere, lo, hi, o);
  EXPECT_EQ(r.best_x, r2.best_x);
  // Rosenbrock, minimum 0 at (1, 1); Himmelblau-like box with the optimum on a bound.
  auto rosen = [](const Eigen::VectorXd& x) { return 100 * std::pow(x[1] - x[0] * x[0], 2) + std::pow(1 - x[0], 2); };
  Eigen::VectorXd l2(2), h2(2);
  l2 << -2, -1;
  h2 << 2, 3;
  o.iterations = 300;
  const PsoResult rr = pso_minimize(rosen, l2, h2, o);
  EXPECT_LT(std::abs(rr.best_x[0] - 1.0), 0.05);
  EXPECT_LT(std::abs(rr.best_x[1] - 1.0), 0.1);
  auto onbound = [](const Eigen::VectorXd& x) { return x[0] + (x[1] - 0.5) * (x[1] - 0.5); };
  const PsoResult rb = pso_minimize(onbound, l2, h2, o);
  EXPECT_NEAR(rb.best_x[0], -2.0, 1e-9);
  EXPECT_NEAR(rb.best_x[1], 0.5, 1e-3);
  EXPECT_THROW(pso_minimize(sphere, hi, lo, o), std::invalid_argument);
}

TEST(Tuning, CartesianOnlySwarmBeatsDefaultsWithinNozzleLimits) {
  const auto passes = axial_region(8, 1.2, 0.2, 0.0, 1.0, {0.25, 0.2});
  for (double amax : {2.0, 1.2}) {
    TimingConfig tc;
    tc.nozzle_max_accel_mps2 = amax;
    const TimingTuning t = tune_timing(nullptr, {passes}, Eigen::VectorXd(), tc, RobotConfig{});
    // Defaults: start peak 2 v / t1 = 1.875 m/s^2 at 0.25 m/s, end 1.2 at 0.2 -> feasible at 2.0 only.
    EXPECT_EQ(t.initial_feasible, amax == 2.0);
    if (t.initial_feasible) {
      EXPECT_LE(t.duration_s, t.initial_duration_s);
    }
    ASSERT_LT(t.duration_s, 1e5) << "no feasible timing found at " << amax;
    ASSERT_EQ(t.feasible, std::vector<char>{1}) << "the swarm fell back to the config at " << amax;
    // Re-check the tuned particle independently, on a finer sampling.
    ASSERT_EQ(t.params.size(), 1u);
    const TimingParams& tuned = t.params[0];
    const CartesianPath path = timing_region_path(passes, tuned.start_length_m, tuned.end_length_m, tc);
    const SpeedProfile prof = region_profile(path, tuned);
    EXPECT_NEAR(prof.duration_s(), t.duration_s, 1e-9);
    EXPECT_LE(check_nozzle(path, prof, NozzleLimits{tc.nozzle_max_speed_mps, amax}, 2000.0).accel_ratio, 1.0 + 1e-3);
  }
}

TEST(RobotTiming, TunedRegionsRespectJointLimits) {
  const Robot robot = Robot::load(RobotConfig{});
  const RobotConfig rc;
  TimingConfig tc;
  // Two regions of a 5.6 m wall (nozzle at 1 m standoff): 4 axial passes each, 0.2 m apart.
  const std::vector<std::vector<Pass>> regions{axial_region(4, 1.2, 0.2, 0.0, 1.2, {0.25, 0.2}),
                                               axial_region(3, 1.0, 0.2, 0.1, 0.7, {0.3})};
  const TimingTuning tun = tune_timing(&robot, regions, robot.neutral(), tc, rc);
  ASSERT_LT(tun.duration_s, 1e5) << "no feasible timing";
  ASSERT_EQ(tun.feasible, std::vector<char>(regions.size(), 1)) << "the swarm fell back to the config";
  ASSERT_EQ(tun.params.size(), regions.size());
  const TimedTrajectory tr = time_plan(robot, regions, robot.neutral(), tc, rc, tun.params);
  EXPECT_EQ(tr.untracked_regions, 0);
  // Finite-difference velocities / accelerations of the sampled joint path within the limits
  // (the swarm judged them on its arc-length model; the tolerance covers the two discretisations).
  EXPECT_LE(tr.max_velocity_ratio, 1.0 + 1e-3);
  EXPECT_LE(tr.max_acceleration_ratio, 1.03);
  EXPECT_LE(tr.max_position_violation_rad, 0.0);
  // Region durations are those of the tuned profiles; the transits (joint quintics between the
  // regions' end configurations) may differ slightly from the swarm's model.
  double regions_s = 0.0;
  for (std::size_t r = 0; r < regions.size(); ++r) {
    const TimingParams& p = tun.params[r];
    const CartesianPath path = timing_region_path(regions[r], p.start_length_m, p.end_length_m, tc);
    regions_s += region_profile(path, p).duration_s();
  }
  EXPECT_NEAR(tr.duration_s - tr.transit_time_s, regions_s, 1e-9);
  EXPECT_NEAR(tr.duration_s, tun.duration_s, 0.01 * tun.duration_s);
  ASSERT_EQ(tr.q.size(), tr.size());
  ASSERT_EQ(tr.qdd.size(), tr.size());
  double pass_time = 0.0;
  for (const auto& reg : regions)
    for (const auto& p : reg) pass_time += p.length_m / p.speed_mps;
  EXPECT_NEAR(tr.spray_time_s, pass_time, 1e-6);
  double dwell = 0.0;
  for (double d : spray_dwells(tr.t_s, tr.spraying)) dwell += d;
  EXPECT_NEAR(dwell, pass_time, 7.0 / tc.trajectory_rate_hz);  // within a sample per pass
  int checked = 0, transit = 0;
  for (std::size_t i = 0; i < tr.size(); ++i) {
    if (i > 0) {
      ASSERT_LE(tr.t_s[i] - tr.t_s[i - 1], 1.0 / tc.trajectory_rate_hz + 1e-12);
    }
    const Eigen::Isometry3d T = robot.fk(tr.q[i]);
    if (tr.kind[i] == static_cast<char>(SegmentKind::Transit)) {
      ++transit;
      EXPECT_EQ(tr.region_index[i], -1);
      continue;
    }
    // FK of the timed joints is the nozzle pose of the sample (exact tracking).
    ASSERT_LT((T.translation() - tr.nozzle[i].position_m).norm(), 1e-6) << "sample " << i;
    ASSERT_LT(std::acos(std::min(1.0, T.linear().col(2).dot(tr.nozzle[i].axis))), 1e-5) << "sample " << i;
    // J(q) qd reproduces the planned nozzle speed on the passes (independent of the profile code).
    if (tr.kind[i] == static_cast<char>(SegmentKind::Pass) && i + 1 < tr.size() &&
        tr.kind[i - 1] == tr.kind[i] && tr.kind[i + 1] == tr.kind[i]) {
      const double v = (robot.jacobian(tr.q[i]).topRows<3>() * tr.qd[i]).norm();
      const auto& reg = regions[static_cast<std::size_t>(tr.region_index[i])];
      const int first = tr.region_index[i] == 0 ? 0 : static_cast<int>(regions[0].size());
      ASSERT_NEAR(v, reg[static_cast<std::size_t>(tr.pass_index[i] - first)].speed_mps, 2e-3) << "sample " << i;
      ++checked;
    }
  }
  EXPECT_GT(checked, 500);
  EXPECT_GT(transit, 10);
  EXPECT_GT(tr.transit_time_s, 0.0);
  // The CSV carries every sample.
  const std::string csv = tr.to_csv();
  EXPECT_EQ(static_cast<std::size_t>(std::count(csv.begin(), csv.end(), '\n')), tr.size() + 1);
  EXPECT_EQ(tr.joint_table().cols(), 1 + 3 * robot.dof());
  // The config's untuned defaults start too hard for the slew joint (the swarm's model says so, and
  // this check failed before time_plan re-timed regions): time_plan's joint check lengthens the
  // leads until the joints are within their limits, so the region takes longer than its nominal
  // profile.
  EXPECT_FALSE(tun.initial_feasible);
  const TimedTrajectory raw = time_plan(robot, {regions[0]}, robot.neutral(), tc, rc);
  EXPECT_LE(raw.max_acceleration_ratio, 1.0);
  const TimingParams nominal = TimingParams::from_config(tc);
  const double nominal_s =
      region_profile(timing_region_path(regions[0], nominal.start_length_m, nominal.end_length_m, tc), nominal)
          .duration_s();
  EXPECT_GT(raw.duration_s - raw.transit_time_s, nominal_s + 0.05);
}

TEST(RobotTiming, StopAndGoMovesHappenInJointSpace) {
  // Two axial passes both heading +x on neighbouring lines: stop-and-go between them. The move
  // from the run-out's end to the run-in's start is a joint quintic at the limits (kind Transit
  // inside the region), not a straight nozzle line.
  auto passes = axial_region(2, 1.0, 0.3, 0.0, 1.2, {0.2});
  std::reverse(passes[1].waypoints.begin(), passes[1].waypoints.end());
  const Robot robot = Robot::load(RobotConfig{});
  const TimingConfig tc;
  const TimedTrajectory tr = time_plan(robot, {passes}, robot.neutral(), tc, RobotConfig{});
  EXPECT_EQ(tr.untracked_regions, 0);
  std::size_t first = tr.size(), last = 0;
  for (std::size_t i = 0; i < tr.size(); ++i)
    if (tr.kind[i] == static_cast<char>(SegmentKind::Transit) && tr.region_index[i] == 0)
      first = std::min(first, i), last = std::max(last, i);
  ASSERT_LT(first, last) << "no joint-space move inside the region";
  // At rest at both ends; its duration is the minimal quintic between them.
  const Eigen::VectorXd& q0 = tr.q[first - 1];
  const Eigen::VectorXd& q1 = tr.q[last];
  const double T = quintic_min_duration(q0, q1, robot.velocity_limits(), robot.acceleration_limits());
  EXPECT_NEAR(tr.t_s[last] - tr.t_s[first - 1], T, 1e-9);
  for (std::size_t i = first; i <= last; ++i) {
    Eigen::VectorXd q, qd, qdd;
    quintic_joint(q0, q1, T, tr.t_s[i] - tr.t_s[first - 1], q, qd, qdd);
    ASSERT_LT((q - tr.q[i]).cwiseAbs().maxCoeff(), 1e-12);
  }
  EXPECT_LE(tr.max_velocity_ratio, 1.0 + 1e-3);
  EXPECT_LE(tr.max_acceleration_ratio, 1.03);
}

TEST(RobotTiming, BadInput) {
  const Robot robot = Robot::load(RobotConfig{});
  EXPECT_THROW(time_plan(robot, {}, Eigen::VectorXd::Zero(3), TimingConfig{}, RobotConfig{}), std::invalid_argument);
  auto passes = axial_region(2, 1.0, 0.2, 0.0, 1.0, {0.2});
  passes[1].speed_mps = 0.0;
  EXPECT_THROW(time_plan(robot, {passes}, robot.neutral(), TimingConfig{}, RobotConfig{}), std::invalid_argument);
  // A pass far outside the reach: a runtime_error naming the region.
  auto far = axial_region(2, 1.0, 0.2, 30.0, 1.0, {0.2});
  try {
    time_plan(robot, {far}, robot.neutral(), TimingConfig{}, RobotConfig{});
    FAIL() << "no error for an unreachable region";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("region 0"), std::string::npos) << e.what();
  }
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
  const CartesianPath path = region_path({a, b}, 0.1, 0.1, false, 0, 0.1);
  int gaps = 0;
  for (const auto& piece : path.pieces())
    if (piece.motion == 4) {
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

TEST(RegionPath, StopAndGoRunsGrowWithThePassSpeed) {
  // Two passes along +x on neighbouring lines (not a serpentine): stop-and-go between them. At
  // 0.8 m/s and 0.5 m/s^2 the plain cycloidal stop needs 0.8^2 / 0.5 = 1.28 m (a k2 = 0.5 cruise
  // would need 3.84 m).
  auto line = [](double z) {
    Pass p;
    for (double x = 0.0; x <= 1.2 + 1e-9; x += 0.01) p.waypoints.push_back({Eigen::Vector3d(x, 0, z), Eigen::Vector3d(0, 0, 1)});
    p.length_m = 1.2;
    p.speed_mps = 0.8;
    return p;
  };
  const std::vector<Pass> passes = {line(4.6), line(4.8)};
  const CartesianPath fixed = region_path(passes, 0.1, 0.1, false, 0, 0.1);
  const CartesianPath grown = region_path(passes, 0.1, 0.1, false, 0, 0.1, 0.5);
  double out_fixed = 0, out_grown = 0;
  for (const auto& p : fixed.pieces())
    if (p.motion == 1) out_fixed = p.length_m();
  for (const auto& p : grown.pieces())
    if (p.motion == 1) out_grown = p.length_m();
  EXPECT_NEAR(out_fixed, 0.1, 1e-9);
  EXPECT_NEAR(out_grown, 0.8 * 0.8 / 0.5, 1e-9);
  // The stop then peaks at the acceleration limit.
  TimingParams prm = TimingParams::from_config(TimingConfig{});
  prm.k1 = prm.k2 = 0.5;
  const SpeedProfile prof = region_profile(grown, prm);
  ASSERT_EQ(grown.pieces()[2].motion, 1);  // lead-in, pass, run-out, ...
  const double t_from = prof.time_at_distance(grown.piece_start_m(2)), t_stop = prof.time_at_distance(grown.piece_start_m(3));
  double peak = 0.0;
  for (double t = t_from; t <= t_stop; t += 0.001) peak = std::max(peak, std::abs(prof.at(t).a_mps2));
  EXPECT_GT(peak, 0.45);
  EXPECT_LT(peak, 0.5 + 1e-3);
  // Per-gap scales ease only their own gap: a third line, the second gap at half the acceleration.
  const std::vector<Pass> three = {line(4.6), line(4.8), line(5.0)};
  const CartesianPath eased = region_path(three, 0.1, 0.1, false, 0, 0.1, 0.5, 0.0, 0.0, {1.0, 0.5});
  std::vector<double> outs, ins;
  for (const auto& p : eased.pieces()) {
    if (p.motion == 1) outs.push_back(p.length_m());
    if (p.motion == 3) ins.push_back(p.length_m());
  }
  ASSERT_EQ(outs.size(), 2u);
  ASSERT_EQ(ins.size(), 2u);
  EXPECT_NEAR(outs[0], 0.64 / 0.5, 1e-9);
  EXPECT_NEAR(ins[0], 0.64 / 0.5, 1e-9);
  EXPECT_NEAR(outs[1], 0.64 / 0.25, 1e-9);
  EXPECT_NEAR(ins[1], 0.64 / 0.25, 1e-9);
  // One scale per gap, each in (0, 1].
  EXPECT_THROW(region_path(three, 0.1, 0.1, false, 0, 0.1, 0.5, 0.0, 0.0, {1.0}), std::invalid_argument);
  EXPECT_THROW(region_path(three, 0.1, 0.1, false, 0, 0.1, 0.5, 0.0, 0.0, {1.0, 0.0}), std::invalid_argument);
  EXPECT_THROW(region_path(three, 0.1, 0.1, false, 0, 0.1, 0.5, 0.0, 0.0, {1.5, 1.0}), std::invalid_argument);
  EXPECT_THROW(region_path(three, 0.1, 0.1, false, 0, 0.1, 0.5, 0.0, 0.0, {NAN, 1.0}), std::invalid_argument);
}

TEST(Joint, SpeedLimitsPutTheBindingJointAtItsLimit) {
  // The nozzle pose of the ready posture swung 0.6 rad about the slew axis. Reference: the tracked
  // joint path timed at each waypoint's cap, with velocities and accelerations differenced in time
  // (t = s / v): the worst joint is then exactly at its limit there, and the slew does most of the
  // turning (at most 1 / rho rad per metre; the redundant joints take a little of it).
  const Robot robot = Robot::load(RobotConfig{});
  const Eigen::VectorXd q0 = robot.neutral();
  const Eigen::Isometry3d T0 = robot.fk(q0);
  const Eigen::Vector3d c = RobotConfig{}.base_position_m;  // the slew axis is vertical through it
  const double rho = Eigen::Vector2d(T0.translation().x() - c.x(), T0.translation().y() - c.y()).norm();
  ASSERT_GT(rho, 1.0);
  std::vector<NozzlePose> poses;
  for (int k = -150; k <= 150; ++k) {
    const Eigen::AngleAxisd R(0.002 * k, Eigen::Vector3d::UnitZ());
    NozzlePose p;
    p.position_m = c + R * (T0.translation() - c);
    p.axis = R * T0.linear().col(2);
    poses.push_back(p);
  }
  const Eigen::VectorXd vl = robot.velocity_limits(), al = robot.acceleration_limits();
  const auto cap = joint_speed_limits(robot, poses, q0, 0.0, 1.0);
  ASSERT_EQ(cap.size(), poses.size());
  const auto q = track_joint_path(robot, poses, q0);
  for (std::size_t k = 1; k + 1 < poses.size(); ++k) {
    const double v = cap[k];
    ASSERT_GT(v, 0.9 * vl[0] * rho) << k;
    ASSERT_LT(v, 1.2 * vl[0] * rho) << k;
    const double t0 = -(poses[k].position_m - poses[k - 1].position_m).norm() / v,
                 t2 = (poses[k + 1].position_m - poses[k].position_m).norm() / v;
    const Eigen::VectorXd qd = (q[k + 1] - q[k - 1]) / (t2 - t0);
    const Eigen::VectorXd qdd = ((q[k + 1] - q[k]) / t2 - (q[k] - q[k - 1]) / -t0) / (0.5 * (t2 - t0));
    const double ratio = std::max(qd.cwiseAbs().cwiseQuotient(vl).maxCoeff(), qdd.cwiseAbs().cwiseQuotient(al).maxCoeff());
    ASSERT_NEAR(ratio, 1.0, 1e-6) << k;
  }
  // A limit share scales the velocity bound (the speed changes below cost the slew about half its
  // acceleration); a tangential acceleration beyond what the slew can give allows no speed.
  const auto shared = joint_speed_limits(robot, poses, q0, 0.5 * al[0] * rho, 0.8);
  for (std::size_t k = 0; k < cap.size(); ++k) ASSERT_LE(shared[k], 0.8 * cap[k] * (1 + 1e-9)) << k;
  const auto none = joint_speed_limits(robot, poses, q0, 1.3 * al[0] * rho, 1.0);
  for (std::size_t k = 0; k < none.size(); ++k) ASSERT_EQ(none[k], 0.0) << k;
  EXPECT_THROW(joint_speed_limits(robot, poses, q0, 0.0, 0.0), std::invalid_argument);
  EXPECT_THROW(joint_speed_limits(robot, poses, q0, -1.0, 1.0), std::invalid_argument);
}

TEST(ArmPlan, SpeedCapMapLearnsFromLimitBreakingSamples) {
  // A straight pass at 0.5 m/s whose middle sample breaks joint 0's velocity limit 2x and joint 1's
  // acceleration limit 3x; a link sample over an acceleration limit only (not the planner's).
  const Eigen::VectorXd vel = Eigen::VectorXd::Constant(2, 1.0), acc = Eigen::VectorXd::Constant(2, 1.0);
  TimedTrajectory tr;
  for (int i = 0; i < 9; ++i) {
    tr.t_s.push_back(0.1 * i);
    NozzlePose p;
    p.position_m = Eigen::Vector3d(0.05 * i, 0, 0);
    tr.nozzle.push_back(p);
    tr.q.push_back(Eigen::VectorXd::Zero(2));
    tr.qd.push_back(Eigen::VectorXd::Constant(2, 0.5));
    tr.qdd.push_back(Eigen::VectorXd::Zero(2));
    tr.spraying.push_back(i < 6);
    tr.pass_index.push_back(i < 6 ? 0 : -1);
    tr.region_index.push_back(0);
    tr.kind.push_back(static_cast<char>(i < 6 ? SegmentKind::Pass : SegmentKind::Link));
  }
  tr.qd[3] = Eigen::Vector2d(2.0, 0.5);
  tr.qdd[3] = Eigen::Vector2d(0.0, 3.0);
  tr.qdd[7] = Eigen::Vector2d(5.0, 0.0);
  SpeedCapMap map;
  EXPECT_EQ(map.learn(tr, vel, acc, 0.9), 2);
  ASSERT_EQ(map.speed_mps.size(), 2u);
  // min(0.9 / 2, sqrt(0.9 / 3)) * 0.5 m/s
  EXPECT_NEAR(map.speed_mps[0], 0.5 * std::min(0.45, std::sqrt(0.3)), 1e-12);
  EXPECT_NEAR(map.at(Eigen::Vector3d(0.15 - 0.09, 0, 0)), map.speed_mps[0], 1e-12);
  EXPECT_TRUE(std::isinf(map.at(Eigen::Vector3d(0.15 - 0.11, 0, 0))));
  // The link sample over the acceleration limit (its run stops from the pass end): the bound goes
  // to the last pass sample (5), sqrt(0.9 / 5) of its speed.
  EXPECT_EQ(map.points_m[1], tr.nozzle[5].position_m);
  EXPECT_NEAR(map.speed_mps[1], 0.5 * std::sqrt(0.9 / 5.0), 1e-12);
  // A link sample over a velocity limit counts at its own position: it cruises at the speed of a
  // pass next to it.
  tr.qdd[7].setZero();
  tr.qd[7] = Eigen::Vector2d(0.0, 1.5);
  EXPECT_EQ(map.learn(tr, vel, acc, 0.9), 2);  // sample 3 again, and sample 7
  EXPECT_EQ(map.points_m.back(), tr.nozzle[7].position_m);
  EXPECT_NEAR(map.speed_mps.back(), 0.5 * 0.9 / 1.5, 1e-12);
  // A run-in (the link comes after a joint move and before a pass): the next pass's first sample.
  TimedTrajectory in = tr;
  for (int i = 0; i < 9; ++i) {
    in.kind[i] = static_cast<char>(i < 2 ? SegmentKind::Transit : i < 4 ? SegmentKind::Link : SegmentKind::Pass);
    in.spraying[i] = i >= 4;
    in.qd[i] = Eigen::Vector2d(0.0, 0.5);
    in.qdd[i].setZero();
  }
  in.qdd[2] = Eigen::Vector2d(0.0, 4.0);
  SpeedCapMap run_in;
  EXPECT_EQ(run_in.learn(in, vel, acc, 0.9), 1);
  EXPECT_EQ(run_in.points_m[0], in.nozzle[4].position_m);
  EXPECT_NEAR(run_in.speed_mps[0], 0.5 * std::sqrt(0.9 / 4.0), 1e-12);
}

TEST(RobotTiming, JointModelAgreesWithTimePlan) {
  // The swarm's arc-length model against the sampled trajectory (a second method: IK per sample,
  // finite differences in time) on a region with turns and a stop-and-go move: same duration (the
  // joint move's quintic included) and about the same worst joint ratios.
  auto passes = axial_region(3, 1.0, 0.2, 0.0, 1.2, {0.2, 0.25, 0.15});
  auto last = axial_region(4, 1.0, 0.2, 0.0, 1.2, {0.2})[3];
  std::reverse(last.waypoints.begin(), last.waypoints.end());  // heads like pass 2: stop and go
  passes.push_back(last);
  const Robot robot = Robot::load(RobotConfig{});
  const RobotConfig rc;
  TimingConfig tc;
  TimingParams p = TimingParams::from_config(tc);
  p.k1 = 0.8;  // gentle enough that time_plan keeps the geometry (no easing)
  p.k2 = 0.2;
  p.start_length_m = p.end_length_m = 0.3;
  const RegionJointModel model(robot, passes, tc.max_lead_length_m, tc, robot.neutral(), rc);
  ASSERT_TRUE(model.tracked());
  const auto ev = model.evaluate(p, NozzleLimits{tc.nozzle_max_speed_mps, tc.nozzle_max_accel_mps2});
  const TimedTrajectory tr = time_plan(robot, {passes}, robot.neutral(), tc, rc, {p});
  ASSERT_LE(tr.max_acceleration_ratio, 1.0) << "time_plan eased the region: the geometries differ";
  int moves = 0;
  for (std::size_t i = 0; i < tr.size(); ++i) moves += tr.kind[i] == static_cast<char>(SegmentKind::Transit) && tr.region_index[i] == 0;
  ASSERT_GT(moves, 0) << "no stop-and-go move";
  const double transit = quintic_min_duration(robot.neutral(), ev.q_first, robot.velocity_limits(), robot.acceleration_limits());
  EXPECT_NEAR(ev.duration_s + transit, tr.duration_s, 1e-3 * tr.duration_s);  // measured: 1e-5
  // Worst ratios off the joint moves (the model skips them).
  double vel = 0.0, acc = 0.0;
  for (std::size_t i = 0; i < tr.size(); ++i) {
    if (tr.kind[i] == static_cast<char>(SegmentKind::Transit)) continue;
    vel = std::max(vel, tr.qd[i].cwiseAbs().cwiseQuotient(robot.velocity_limits()).maxCoeff());
    acc = std::max(acc, tr.qdd[i].cwiseAbs().cwiseQuotient(robot.acceleration_limits()).maxCoeff());
  }
  EXPECT_NEAR(ev.velocity_ratio, vel, 0.01 * vel);  // measured: 4e-5
  EXPECT_NEAR(ev.acceleration_ratio, acc, 0.01 * acc);
  // One parameter set per region or none; anything else names the mismatch.
  EXPECT_THROW(time_plan(robot, {passes}, robot.neutral(), tc, rc, {p, p}), std::invalid_argument);
}
