// The executed deposit: the pump's flow schedule, the deposit along a known trajectory against a
// brute-force integration written here, the mass balance, and a pass with a speed step against
// the closed-form stroke.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <stdexcept>

#include "shotcrete/deposition/deposition.hpp"
#include "shotcrete/deposition/wall.hpp"
#include "shotcrete/pipeline/executed_deposit.hpp"
#include "shotcrete/timing/region_spray.hpp"
#include "shotcrete/timing/sampling.hpp"
#include "bay_fixtures.hpp"
#include "timing_fixtures.hpp"

using namespace shotcrete;

namespace {

std::vector<double> times(int n, double dt) {
  std::vector<double> t(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) t[static_cast<std::size_t>(i)] = i * dt;
  return t;
}

FlowConfig flow(double ramp, double min_on, double min_off) {
  FlowConfig f;
  f.ramp_s = ramp, f.min_on_s = min_on, f.min_off_s = min_off;
  return f;
}

// The test's own flow: piecewise linear through its kinks (t, value), integrated exactly by the
// trapezoid rule between the kinks.
struct KinkFlow {
  std::vector<double> t, f;
  KinkFlow(const std::vector<std::pair<double, double>>& spells, double ramp) {
    t.push_back(-1e9), f.push_back(0.0);
    for (auto [on, off] : spells) {
      t.insert(t.end(), {on - ramp / 2, on + ramp / 2, off - ramp / 2, off + ramp / 2});
      f.insert(f.end(), {0.0, 1.0, 1.0, 0.0});
    }
    t.push_back(1e9), f.push_back(0.0);
  }
  double value(double x) const {
    for (std::size_t k = 0; k + 1 < t.size(); ++k)
      if (x >= t[k] && x <= t[k + 1]) return t[k + 1] > t[k] ? f[k] + (f[k + 1] - f[k]) * (x - t[k]) / (t[k + 1] - t[k]) : f[k + 1];
    return 0.0;
  }
  double integral(double a, double b) const {
    std::vector<double> xs{a, b};
    for (double x : t)
      if (x > a && x < b) xs.push_back(x);
    std::sort(xs.begin(), xs.end());
    double s = 0.0;
    for (std::size_t k = 0; k + 1 < xs.size(); ++k) s += 0.5 * (value(xs[k]) + value(xs[k + 1])) * (xs[k + 1] - xs[k]);
    return s;
  }
  // Dwell of every sample: its share between the midpoints with its neighbours, the ends open.
  std::vector<double> dwells(const std::vector<double>& ts) const {
    std::vector<double> d;
    for (std::size_t i = 0; i < ts.size(); ++i) {
      const double lo = i == 0 ? -1e8 : 0.5 * (ts[i - 1] + ts[i]), hi = i + 1 == ts.size() ? 1e8 : 0.5 * (ts[i] + ts[i + 1]);
      d.push_back(integral(lo, hi));
    }
    return d;
  }
};

}  // namespace

namespace {
// The schedule's spells are these [on, off] pairs (by hand).
void expect_spells(const FlowSchedule& s, const std::vector<std::pair<double, double>>& spells) {
  ASSERT_EQ(s.on_s.size(), spells.size());
  for (std::size_t k = 0; k < spells.size(); ++k) {
    EXPECT_NEAR(s.on_s[k], spells[k].first, 1e-9) << "spell " << k;
    EXPECT_NEAR(s.off_s[k], spells[k].second, 1e-9) << "spell " << k;
  }
}
}  // namespace

TEST(FlowSchedule, IdealPumpGivesTheSprayDwells) {
  std::mt19937 rng(3);
  std::vector<double> t = times(400, 0.02);
  std::vector<char> spraying(t.size());
  for (auto& s : spraying) s = static_cast<char>(rng() % 3 != 0);
  const FlowSchedule s = flow_schedule(t, spraying, flow(0.0, 0.0, 0.0));
  const std::vector<double> d = flow_dwells(s, t), ref = spray_dwells(t, spraying);
  for (std::size_t i = 0; i < t.size(); ++i) EXPECT_NEAR(d[i], ref[i], 1e-12) << i;
  EXPECT_EQ(s.switches(), s.commanded_switches);
  EXPECT_DOUBLE_EQ(s.bridged_s + s.extended_s, 0.0);
}

TEST(FlowSchedule, BridgesShortGapsAndExtendsShortSpells) {
  const std::vector<double> t = times(61, 0.1);  // 0 .. 6 s
  std::vector<char> spraying(t.size(), 0);
  for (int i = 5; i <= 14; ++i) spraying[static_cast<std::size_t>(i)] = 1;   // [0.45, 1.45]
  for (int i = 20; i <= 30; ++i) spraying[static_cast<std::size_t>(i)] = 1;  // [1.95, 3.05]
  spraying[50] = 1;                                                           // [4.95, 5.05]
  const FlowSchedule s = flow_schedule(t, spraying, flow(0.5, 1.0, 1.0));
  ASSERT_EQ(s.on_s.size(), 2u);
  EXPECT_NEAR(s.on_s[0], 0.45, 1e-12);
  EXPECT_NEAR(s.off_s[0], 3.05, 1e-12);  // the 0.5 s gap bridged
  EXPECT_NEAR(s.on_s[1], 4.5, 1e-12);    // 0.1 s extended to 1 s about its middle
  EXPECT_NEAR(s.off_s[1], 5.5, 1e-12);
  EXPECT_NEAR(s.bridged_s, 0.5, 1e-12);
  EXPECT_NEAR(s.extended_s, 0.9, 1e-12);
  EXPECT_NEAR(s.commanded_on_s, 1.0 + 1.1 + 0.1, 1e-12);
  EXPECT_EQ(s.commanded_switches, 6);
  EXPECT_EQ(s.switches(), 4);
  // Ramps centred: half flow at each switch, and each spell lays its length at full flow.
  EXPECT_NEAR(s.flow_at(0.45), 0.5, 1e-12);
  EXPECT_NEAR(s.flow_at(5.5), 0.5, 1e-12);
  EXPECT_NEAR(s.flow_at(0.2), 0.0, 1e-12);
  EXPECT_NEAR(s.flow_at(0.7), 1.0, 1e-12);
  const std::vector<double> d = flow_dwells(s, t);
  double sum = 0.0;
  for (double x : d) sum += x;
  EXPECT_NEAR(sum, s.commanded_on_s + s.bridged_s + s.extended_s, 1e-12);
  const KinkFlow ref({{0.45, 3.05}, {4.5, 5.5}}, 0.5);
  const std::vector<double> dr = ref.dwells(t);
  for (std::size_t i = 0; i < t.size(); ++i) EXPECT_NEAR(d[i], dr[i], 1e-12) << i;
}

TEST(FlowSchedule, NoSpellShorterThanTheMinimums) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 20; ++trial) {
    const std::vector<double> t = times(2000, 0.02);
    std::vector<char> spraying(t.size(), 0);
    char state = 0;
    for (auto& s : spraying) {
      if (rng() % 25 == 0) state = static_cast<char>(!state);
      s = state;
    }
    const FlowConfig f = flow(0.3, 1.5, 0.8);
    const FlowSchedule s = flow_schedule(t, spraying, f);
    if (s.on_s.empty()) continue;
    EXPECT_GE(s.shortest_on_s(), f.min_on_s - 1e-9);
    if (s.on_s.size() > 1) EXPECT_GE(s.shortest_off_s(), f.min_off_s - 1e-9);
    // Whatever the flags ask for is sprayed, but for the ends trimmed off spells to widen short
    // gaps: the flagged samples outside every spell add up to the trimmed time (to a sample's
    // share at each end of a spell).
    double outside_s = 0.0;
    for (std::size_t i = 0; i < t.size(); ++i) {
      if (!spraying[i]) continue;
      bool inside = false;
      for (std::size_t k = 0; k < s.on_s.size(); ++k) inside = inside || (t[i] >= s.on_s[k] && t[i] <= s.off_s[k]);
      if (!inside) outside_s += 0.02;
    }
    EXPECT_LE(outside_s, s.trimmed_s + 0.02 * 2.0 * static_cast<double>(s.on_s.size()) + 1e-9);
    EXPECT_NEAR(s.on_time_s(), s.commanded_on_s + s.bridged_s + s.extended_s - s.dropped_s - s.trimmed_s, 1e-9);
    EXPECT_GE(s.bridged_s, 0.0);
    EXPECT_GE(s.extended_s, -1e-9);
  }
}

// A short spell between two turns of the pump's minimum off time: extending it brings both gaps
// under the minimum, and the pump widens them by switching off earlier and on later around it
// (the spell itself, at its minimum, keeps its length), whether or not the trajectory has a joint
// move somewhere else. It used to be switched off when it had (the joint move's check took every
// short gap for its own), so a region's schedule and the whole trajectory's disagreed.
TEST(FlowSchedule, AJointMoveElsewhereDoesNotChangeTheSpells) {
  const std::vector<double> t = times(301, 0.1);  // 0 .. 30 s
  std::vector<char> spraying(t.size(), 0), blocked(t.size(), 0);
  for (int i = 10; i <= 44; ++i) spraying[static_cast<std::size_t>(i)] = 1;   // [0.95, 4.45]
  for (int i = 66; i <= 80; ++i) spraying[static_cast<std::size_t>(i)] = 1;   // [6.55, 8.05]: 1.5 s
  for (int i = 102; i <= 130; ++i) spraying[static_cast<std::size_t>(i)] = 1; // [10.15, 13.05]
  for (int i = 230; i <= 260; ++i) spraying[static_cast<std::size_t>(i)] = 1; // [22.95, 26.05]
  const FlowConfig f = flow(2.0, 2.0, 2.0);
  const FlowSchedule alone = flow_schedule(t, spraying, f);
  for (int i = 200; i <= 210; ++i) blocked[static_cast<std::size_t>(i)] = 1;  // joint move [19.95, 21.05]
  const FlowSchedule with_move = flow_schedule(t, spraying, f, blocked);
  // By hand: the 1.5 s spell grows to 2 s, [6.3, 8.3], leaving gaps of 1.85 s; each is widened
  // to 2 s by 0.15 s off the longer spell beside it (the 2 s spell has none to spare).
  for (const FlowSchedule* s : {&alone, &with_move}) {
    expect_spells(*s, {{0.95, 4.3}, {6.3, 8.3}, {10.3, 13.05}, {22.95, 26.05}});
    EXPECT_NEAR(s->bridged_s, 0.0, 1e-12);
    EXPECT_NEAR(s->trimmed_s, 0.3, 1e-9);
    EXPECT_NEAR(s->dropped_s, 0.0, 1e-12);
    EXPECT_NEAR(s->on_time_s(), s->commanded_on_s + s->extended_s - s->trimmed_s, 1e-9);
  }
}

// A gap a little under min_off is widened (the spells' ends cut: less commanded flow lost than a
// bridge would add, at the turn where the nozzle slows); a gap well under it, or one between
// spells with nothing to spare above min_on, is bridged.
TEST(FlowSchedule, TrimsAShortGapWhenThatCostsLessThanBridgingIt) {
  const std::vector<double> t = times(201, 0.1);  // 0 .. 20 s
  std::vector<char> spraying(t.size(), 0);
  auto spray = [&](int a, int b) {
    for (int i = a; i <= b; ++i) spraying[static_cast<std::size_t>(i)] = 1;
  };
  spray(10, 44);    // [0.95, 4.45]
  spray(61, 90);    // [6.05, 9.05]: a 1.6 s gap before it
  spray(99, 130);   // [9.85, 13.05]: a 0.8 s gap before it
  spray(152, 161);  // [15.15, 16.15]: 1 s, at min_on
  spray(178, 187);  // [17.75, 18.75]: 1 s, 1.6 s after the last
  const FlowConfig f = flow(0.5, 1.0, 2.0);
  const FlowSchedule s = flow_schedule(t, spraying, f);
  // The 1.6 s gap: 0.4 s to cut < 1.6 s to bridge, 0.2 s off each end. The 0.8 s gap: 1.2 s to
  // cut > 0.8 s: bridged. The last gap: both spells at min_on, nothing to cut: bridged.
  expect_spells(s, {{0.95, 4.25}, {6.25, 13.05}, {15.15, 18.75}});
  EXPECT_NEAR(s.trimmed_s, 0.4, 1e-9);
  EXPECT_NEAR(s.bridged_s, 0.8 + 1.6, 1e-9);
  EXPECT_GE(s.shortest_off_s(), f.min_off_s - 1e-9);
  EXPECT_NEAR(s.on_time_s(), s.commanded_on_s + s.bridged_s + s.extended_s - s.trimmed_s, 1e-9);
  double sum = 0.0;
  for (double d : flow_dwells(s, t)) sum += d;
  EXPECT_NEAR(sum, s.on_time_s(), 1e-9);
}

TEST(FlowSchedule, NoFlowThroughAJointMove) {
  const std::vector<double> t = times(101, 0.1);  // 0 .. 10 s
  std::vector<char> spraying(t.size(), 0), blocked(t.size(), 0);
  for (int i = 10; i <= 29; ++i) spraying[static_cast<std::size_t>(i)] = 1;  // [0.95, 2.95]
  for (int i = 32; i <= 36; ++i) blocked[static_cast<std::size_t>(i)] = 1;   // joint move [3.15, 3.65]
  for (int i = 38; i <= 39; ++i) spraying[static_cast<std::size_t>(i)] = 1;  // [3.75, 3.95]: 0.2 s
  for (int i = 41; i <= 45; ++i) blocked[static_cast<std::size_t>(i)] = 1;   // joint move [4.05, 4.55]
  for (int i = 60; i <= 62; ++i) spraying[static_cast<std::size_t>(i)] = 1;  // [5.95, 6.25]: 0.3 s
  for (int i = 70; i <= 74; ++i) blocked[static_cast<std::size_t>(i)] = 1;   // joint move [6.95, 7.45]
  for (int i = 76; i <= 90; ++i) spraying[static_cast<std::size_t>(i)] = 1;  // [7.55, 9.05]
  const FlowConfig f = flow(0.5, 1.0, 1.0);
  // Without the joint moves the pump sprays through the first two; the 0.3 s spell grows to 1 s,
  // [5.6, 6.6], 0.95 s before the last, which starts 0.05 s late to keep the 1 s off.
  const FlowSchedule wet = flow_schedule(t, spraying, f);
  expect_spells(wet, {{0.95, 3.95}, {5.6, 6.6}, {7.6, 9.05}});
  EXPECT_NEAR(wet.trimmed_s, 0.05, 1e-12);
  const FlowSchedule s = flow_schedule(t, spraying, f, blocked);
  // The spell between the first two joint moves has 0.4 - 0.5 s of free time: dropped. The
  // first spell ends half a ramp before the first move (2.95 -> 2.9); the 0.3 s spell grows to
  // 1 s about its middle (its window 4.8 .. 6.7 holds it); the last starts half a ramp after the
  // third move (7.55 -> 7.7).
  ASSERT_EQ(s.on_s.size(), 3u);
  EXPECT_NEAR(s.on_s[0], 0.95, 1e-12);
  EXPECT_NEAR(s.off_s[0], 2.9, 1e-12);
  EXPECT_NEAR(s.on_s[1], 5.6, 1e-12);
  EXPECT_NEAR(s.off_s[1], 6.6, 1e-12);
  EXPECT_NEAR(s.on_s[2], 7.7, 1e-12);
  EXPECT_NEAR(s.off_s[2], 9.05, 1e-12);
  EXPECT_NEAR(s.dropped_s, 0.05 + 0.2 + 0.15, 1e-12);
  EXPECT_NEAR(s.on_time_s(), s.commanded_on_s + s.bridged_s + s.extended_s - s.dropped_s - s.trimmed_s, 1e-12);
  for (std::size_t i = 0; i < t.size(); ++i)
    if (blocked[i]) {
      EXPECT_NEAR(s.flow_at(t[i]), 0.0, 1e-12) << t[i];
      EXPECT_NEAR(s.flow_at(t[i] - 0.05), 0.0, 1e-12) << t[i];
      EXPECT_NEAR(s.flow_at(t[i] + 0.05), 0.0, 1e-12) << t[i];
    }
}

TEST(FlowSchedule, JointMovesKeepTheMinimumsAndStayDry) {
  std::mt19937 rng(11);
  for (int trial = 0; trial < 20; ++trial) {
    const std::vector<double> t = times(2000, 0.02);
    std::vector<char> spraying(t.size(), 0), blocked(t.size(), 0);
    char state = 0;
    for (std::size_t i = 0; i < t.size(); ++i) {
      if (rng() % 25 == 0) state = static_cast<char>(!state);
      spraying[i] = state;
      if (rng() % 150 == 0)  // a joint move of 0.2 - 1 s, where the flags never spray
        for (std::size_t j = i, m = 10 + rng() % 40; j < std::min(t.size(), i + m); ++j) blocked[j] = 1, spraying[j] = 0;
    }
    for (std::size_t i = 0; i < t.size(); ++i)
      if (blocked[i]) spraying[i] = 0;
    const FlowConfig f = flow(0.3, 1.5, 0.8);
    const FlowSchedule s = flow_schedule(t, spraying, f, blocked);
    EXPECT_NEAR(s.on_time_s(), s.commanded_on_s + s.bridged_s + s.extended_s - s.dropped_s - s.trimmed_s, 1e-9);
    EXPECT_GE(s.dropped_s, 0.0);
    if (s.on_s.empty()) continue;
    EXPECT_GE(s.shortest_on_s(), f.min_on_s - 1e-9);
    if (s.on_s.size() > 1) EXPECT_GE(s.shortest_off_s(), f.min_off_s - 1e-9);
    const std::vector<double> d = flow_dwells(s, t);
    for (std::size_t i = 0; i < t.size(); ++i)
      if (blocked[i]) EXPECT_NEAR(d[i], 0.0, 1e-12) << "trial " << trial << " t " << t[i];
  }
}

// Seed 1 of bench_axis (the bay turned 135 deg on an 8 % grade, direction estimated): a region's
// first spell ends its off-ramp 64 ns after a sample's share begins. The running integral read
// that share as -3.6e-15 s, which accumulate_dwells refused ("dwell time 1337 must be finite and
// >= 0") and plan_bay with it. The times and spell are the region's own.
TEST(FlowSchedule, ShareAtTheEndOfARampIsNotNegative) {
  FlowSchedule s;
  s.ramp_s = 2.0;
  s.on_s = {2.3299998515467397};
  s.off_s = {25.72999836064275};
  const std::vector<double> t = {25.0, 26.719998297566043, 26.739998296291766, 26.759998295017486};
  const std::vector<double> d = flow_dwells(s, t);
  const KinkFlow ref({{s.on_s[0], s.off_s[0]}}, s.ramp_s);
  const std::vector<double> dr = ref.dwells(t);
  double sum = 0.0;
  for (std::size_t i = 0; i < t.size(); ++i) {
    EXPECT_GE(d[i], 0.0) << i;
    EXPECT_NEAR(d[i], dr[i], 1e-12) << i;
    sum += d[i];
  }
  EXPECT_NEAR(sum, s.on_time_s(), 1e-12);
  EXPECT_DOUBLE_EQ(d[3], 0.0);  // its share lies wholly after the ramp
  // The same spell against samples every 20 ms, a share's edge swept in 1 ns steps over the last
  // 200 ns of the ramp: no dwell below 0, each the reference's within 1e-12.
  const double ramp_end = s.off_s[0] + 0.5 * s.ramp_s;
  for (int shift = 0; shift < 200; ++shift) {
    std::vector<double> ts;
    for (int k = 0; k < 100; ++k) ts.push_back(ramp_end - 0.01 + 0.02 * (k - 50) - 1e-9 * shift);
    const std::vector<double> dd = flow_dwells(s, ts), rr = ref.dwells(ts);
    for (std::size_t i = 0; i < ts.size(); ++i) {
      ASSERT_GE(dd[i], 0.0) << "shift " << shift << " sample " << i;
      EXPECT_NEAR(dd[i], rr[i], 1e-12) << "shift " << shift << " sample " << i;
    }
  }
}

TEST(FlowSchedule, BadInputIsAnError) {
  const std::vector<double> t = times(10, 0.1);
  const std::vector<char> on(10, 1);
  EXPECT_THROW(flow_schedule(t, on, flow(2.0, 1.0, 3.0)), std::invalid_argument);   // ramp > min_on
  EXPECT_THROW(flow_schedule(t, on, flow(2.0, 3.0, 1.0)), std::invalid_argument);   // ramp > min_off
  EXPECT_THROW(flow_schedule(t, on, flow(-0.1, 1.0, 1.0)), std::invalid_argument);  // out of range
  EXPECT_THROW(flow_schedule(t, on, flow(0.0, 1.0, 1e6)), std::invalid_argument);
  EXPECT_THROW(flow_schedule(t, std::vector<char>(9, 1), flow(0.0, 0.0, 0.0)), std::invalid_argument);
  std::vector<double> back = t;
  back[4] = back[3];
  EXPECT_THROW(flow_schedule(back, on, flow(0.0, 0.0, 0.0)), std::invalid_argument);
  try {
    flow_schedule(t, on, flow(2.0, 1.0, 3.0));
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("flow.ramp_s"), std::string::npos) << e.what();
  }
}

namespace {

// A trajectory of straight nozzle moves across the bay at standoff H0 from the design circle:
// sample i at d(t_i), aiming radially at angle theta; region_index / spraying as given.
struct Move {
  double theta, d0, d1, duration_s;
  int region;
  bool spraying;
};
TimedTrajectory moves_trajectory(const Surface& surface, const std::vector<Move>& moves, double dt, double standoff) {
  TimedTrajectory tr;
  const double R = surface.profile.radius_m;
  double t = 0.0;
  for (const Move& m : moves) {
    const int n = static_cast<int>(std::round(m.duration_s / dt));
    for (int k = 0; k < n; ++k) {
      const double u = (k + 0.5) / n, d = m.d0 + u * (m.d1 - m.d0);
      NozzlePose pose;
      pose.position_m = surface.axis.to_cartesian(R - standoff, m.theta, d);
      pose.axis = surface.axis.radial(m.theta);
      tr.t_s.push_back(t), tr.nozzle.push_back(pose), tr.spraying.push_back(m.spraying ? 1 : 0);
      tr.region_index.push_back(m.region), tr.pass_index.push_back(m.spraying ? 0 : -1), tr.kind.push_back(0);
      t += dt;
    }
  }
  tr.duration_s = tr.t_s.back();
  return tr;
}

// Brute force: sum over samples and every point of point_rate_mps x dwell x (1 - rebound).
Eigen::VectorXd brute_force(const SpotModel& model, const Cloud& cloud, const TimedTrajectory& tr,
                            const std::vector<double>& dwell, const std::vector<char>& use, double rebound) {
  Eigen::VectorXd out = Eigen::VectorXd::Zero(cloud.size());
  for (std::size_t i = 0; i < tr.size(); ++i) {
    if (!use[i] || dwell[i] <= 0) continue;
    for (Eigen::Index p = 0; p < cloud.size(); ++p)
      out[p] += point_rate_mps(model, tr.nozzle[i], cloud.xyz.row(p).transpose(), cloud.normals.row(p).transpose()) *
                dwell[i] * (1.0 - rebound);
  }
  return out;
}

}  // namespace

TEST(ExecutedDeposit, MatchesABruteForceIntegrationRoundByRound) {
  Config cfg;
  cfg.flow = flow(0.4, 0.6, 0.7);  // the 0.3 s gap: 0.4 s to cut off the spells, more than it lasts
  const Surface surface = test::analytic_bay([](double d, double th) { return 0.04 * std::sin(6 * d) * std::cos(4 * th); },
                                             cfg, 0.9, 1.5, 0.8, 3);
  // Round 1: region 0, a pass with a 0.3 s gap (bridged) and a transit; round 2: region 1.
  const std::vector<Move> moves{{1.2, 0.0, 0.4, 1.0, 0, true},  {1.2, 0.4, 0.5, 0.3, 0, false},
                                {1.2, 0.5, 0.8, 1.0, 0, true},  {1.25, 0.8, 0.8, 1.2, -1, false},
                                {1.3, 0.8, 0.0, 1.6, 1, true}, {1.3, 0.0, 0.0, 0.5, 1, false}};
  const TimedTrajectory tr = moves_trajectory(surface, moves, 0.02, 1.0);
  const ExecutedDeposit ex = execute_deposit(surface, std::vector<int>{1, 1}, tr, cfg);
  EXPECT_NEAR(ex.flow.bridged_s, 0.3, 1e-9);
  EXPECT_EQ(ex.flow.switches(), 4);

  // The test's own flow: spells from the flags (midpoints), the 0.3 s gap bridged, the first spell
  // starting half a ramp after the first sample's share (the pump is off before it).
  const double t_end1 = 0.5 * (tr.t_s[114] + tr.t_s[115]), t_on2 = 0.5 * (tr.t_s[174] + tr.t_s[175]);
  ASSERT_TRUE(tr.spraying[114] && !tr.spraying[115] && !tr.spraying[174] && tr.spraying[175]);
  const KinkFlow ref({{0.5 * (tr.t_s[0] + tr.t_s[1]) + 0.5 * cfg.flow.ramp_s, t_end1}, {t_on2, 0.5 * (tr.t_s[254] + tr.t_s[255])}}, cfg.flow.ramp_s);
  const std::vector<double> dwell = ref.dwells(tr.t_s);
  const SpotModel model = spot_model_from_config(cfg.deposition);
  const double rb = cfg.deposition.rebound_fraction;
  std::vector<char> round1(tr.size(), 0), round2(tr.size(), 0);
  for (std::size_t i = 0; i < tr.size(); ++i) (i < 175 ? round1 : round2)[i] = 1;  // the transit is round 1's
  SprayedWall wall = unsprayed_wall(surface, cfg.profile.max_deviation_m);
  const Eigen::VectorXd d1 = brute_force(model, wall.surface.cloud, tr, dwell, round1, rb);
  deposit_layer(wall, d1);
  const Eigen::VectorXd d2 = brute_force(model, wall.surface.cloud, tr, dwell, round2, rb);
  deposit_layer(wall, d2);
  const Eigen::VectorXd total = d1 + d2;
  ASSERT_EQ(ex.deposited_m.size(), total.size());
  EXPECT_GT(total.maxCoeff(), 0.005);
  for (Eigen::Index p = 0; p < total.size(); ++p) EXPECT_NEAR(ex.deposited_m[p], total[p], 1e-9 * total.maxCoeff()) << p;
  for (int c = 0; c < wall.surface.grid.size(); ++c)
    if (wall.surface.grid.valid[static_cast<std::size_t>(c)]) EXPECT_NEAR(ex.td_after_m[c], wall.surface.grid.td_m[c], 1e-9);
  ASSERT_EQ(ex.round_td_after_m.size(), 2u);
}

TEST(ExecutedDeposit, MassBalanceWithinOnePercent) {
  Config cfg;
  cfg.flow = flow(0.2, 0.5, 0.5);  // short ramps: the 3 s move keeps its spell between the ends
  const Surface surface = test::analytic_bay([](double d, double th) { return 0.03 * std::cos(5 * d) * std::sin(3 * th); },
                                             cfg, 0.9, 1.7, 1.2, 3);
  const SpotModel model = spot_model_from_config(cfg.deposition);
  // Inside the bay, across its edge (d < 0 and d > 1.2), and wholly off it.
  const std::vector<std::vector<Move>> cases{{{1.3, 0.3, 0.9, 4.0, 0, true}},
                                             {{1.1, -0.4, 1.6, 8.0, 0, true}, {1.6, 1.6, -0.4, 8.0, 0, true}},
                                             {{1.3, -1.5, -1.0, 3.0, 0, true}}};
  for (std::size_t k = 0; k < cases.size(); ++k) {
    const TimedTrajectory tr = moves_trajectory(surface, cases[k], 0.02, 1.0);
    const ExecutedDeposit ex = execute_deposit(surface, std::vector<int>{1}, tr, cfg);
    const DepositVolumes& v = ex.volumes;
    EXPECT_NEAR(v.sprayed_m3, model.volume_rate_m3ps() * ex.flow.on_time_s(), 1e-12);
    EXPECT_NEAR(v.rebound_m3, cfg.deposition.rebound_fraction * v.sprayed_m3, 1e-12);
    EXPECT_LT(std::abs(v.balance_error()), 0.01) << "case " << k << ": sprayed " << v.sprayed_m3 << " rebound "
                                                 << v.rebound_m3 << " on wall " << v.on_wall_m3 << " outside " << v.outside_m3;
    if (k == 0) EXPECT_LT(v.outside_m3, 1e-3 * v.sprayed_m3);
    if (k == 1) EXPECT_GT(v.outside_m3, 0.05 * v.sprayed_m3);
    if (k == 2) EXPECT_EQ(v.on_wall_m3, 0.0);
  }
}

TEST(ExecutedDeposit, SpeedStepFollowsTheClosedFormStroke) {
  // A wide, nearly flat bay: the design circle of 50 m radius sags 0.4 mm over the spot.
  Config cfg;
  cfg.profile.design_radius_m = 50.0;
  cfg.flow = flow(0.0, 0.0, 0.0);
  const double mid = 1.5, half = 0.6 / 50.0;
  const Surface surface = test::analytic_bay([](double, double) { return 0.0; }, cfg, mid - half, mid + half, 3.0, 3);
  // 0.1 m/s to d = 1.5, then 0.25 m/s after a 0.5 m/s^2 change centred there, sampled at 500 Hz.
  const double v1 = 0.1, v2 = 0.25, acc = 0.5, dt = 0.002, d_step = 1.5;
  const double t_change = (v2 - v1) / acc, d_a = d_step - 0.5 * (v1 + v2) * t_change / 2;
  TimedTrajectory tr;
  double d = -0.2, v = v1, t = 0.0;
  const double R = surface.profile.radius_m;
  while (d < 3.2) {
    NozzlePose pose;
    pose.position_m = surface.axis.to_cartesian(R - 1.0, mid, d);
    pose.axis = surface.axis.radial(mid);
    tr.t_s.push_back(t), tr.nozzle.push_back(pose), tr.spraying.push_back(1), tr.region_index.push_back(0);
    tr.pass_index.push_back(0), tr.kind.push_back(0);
    v = d < d_a ? v1 : std::min(v2, v + acc * dt);
    d += v * dt, t += dt;
  }
  const ExecutedDeposit ex = execute_deposit(surface, std::vector<int>{1}, tr, cfg);
  const SpotModel model = spot_model_from_config(cfg.deposition);
  const double keep = 1.0 - cfg.deposition.rebound_fraction;
  int far1 = 0, far2 = 0, near = 0;
  for (Eigen::Index p = 0; p < surface.cloud.size(); ++p) {
    const Eigen::Vector3d cyl = surface.axis.to_cylindrical(surface.cloud.xyz.row(p).transpose());
    const double x = (cyl[1] - mid) * R, dp = cyl[2];
    if (std::abs(x) > 0.15) continue;
    const double s1 = stroke_thickness_m(model, x, v1) * keep, s2 = stroke_thickness_m(model, x, v2) * keep;
    const double got = ex.deposited_m[p];
    if (dp > 0.5 && dp < 1.2) {
      EXPECT_NEAR(got, s1, 0.005 * s1) << "d " << dp << " x " << x;
      ++far1;
    }
    if (dp > 1.8 && dp < 2.7) {
      EXPECT_NEAR(got, s2, 0.005 * s2) << "d " << dp << " x " << x;
      ++far2;
    }
    if (std::abs(dp - d_step) < 0.2) {
      EXPECT_LE(got, s1 * 1.005) << dp;
      EXPECT_GE(got, s2 * 0.995) << dp;
      ++near;
    }
  }
  EXPECT_GT(far1, 50);
  EXPECT_GT(far2, 50);
  EXPECT_GT(near, 20);
}

// A region of a trajectory lies between two joint moves: with ends_blocked its first and last
// spells start and end half a ramp inside its ends, and one that then has no room for min_on is
// switched off, as a joint move inside the samples would do (by hand below).
TEST(FlowSchedule, EndsBlockedKeepsTheRampsOffTheTransitsAround) {
  const std::vector<double> t = times(101, 0.1);  // 0 .. 10 s
  std::vector<char> spraying(t.size(), 0);
  for (int i = 3; i <= 30; ++i) spraying[static_cast<std::size_t>(i)] = 1;  // [0.25, 3.05]
  for (int i = 91; i <= 100; ++i) spraying[static_cast<std::size_t>(i)] = 1;  // [9.05, 10]: 0.95 s
  const FlowConfig f = flow(2.0, 2.0, 2.0);
  const FlowSchedule open = flow_schedule(t, spraying, f);
  // Open ends: the first spell as flagged, the last grown to 2 s back from the end.
  expect_spells(open, {{0.25, 3.05}, {8.0, 10.0}});
  const FlowSchedule closed = flow_schedule(t, spraying, f, {}, /*ends_blocked=*/true);
  // Blocked up to 0.05 s (sample 0's share) and from 10.05 s (a sample after the last): free time
  // [1.05, 9.05]; the first spell clipped to start at 1.05 s, the last has no free time left.
  expect_spells(closed, {{1.05, 3.05}});
  EXPECT_NEAR(closed.dropped_s, 0.8 + 0.95, 1e-9);
  // The same as the trajectory has it: sample 0 on the joint move before, one after the last.
  std::vector<double> tp = t;
  tp.push_back(10.1);
  std::vector<char> sp = spraying, blocked(tp.size(), 0);
  sp.push_back(0);
  blocked.front() = blocked.back() = 1;
  const FlowSchedule padded = flow_schedule(tp, sp, f, blocked);
  expect_spells(padded, {{1.05, 3.05}});
  // Nothing flows up to sample 0's share or past the last sample's.
  EXPECT_DOUBLE_EQ(closed.flow_at(0.05), 0.0);
  EXPECT_DOUBLE_EQ(closed.flow_at(10.05), 0.0);
}

// A program laid out on other durations: a 1.98 s spell between two 1.98 s gaps (a planner's 2 s,
// run 1 % faster). The pump's own rules would bridge the first gap (the short spell has nothing to
// cut); the program keeps its three spells, stretched into the slack around them. By hand: the
// gaps widened off the long spells (0.02 s each), the short spell grown 0.02 s about its middle,
// the gaps widened again by 0.01 s off the long spells.
TEST(FlowSchedule, AProgramKeepsItsSpellsWhereItRanShortOfTheMinimums) {
  const std::vector<double> t = times(1501, 0.02);  // 0 .. 30 s; the switches between samples
  const FlowConfig f = flow(1.0, 2.0, 2.0);
  const std::vector<double> on{1.01, 5.99, 9.95}, off{4.01, 7.97, 15.01};
  const FlowSchedule s = program_schedule(on, off, t, f);
  expect_spells(s, {{1.01, 3.98}, {5.98, 7.98}, {9.98, 15.01}});
  EXPECT_NEAR(s.bridged_s, 0.0, 1e-12);
  EXPECT_NEAR(s.trimmed_s, 0.06, 1e-9);
  EXPECT_NEAR(s.extended_s, 0.02, 1e-9);
  EXPECT_NEAR(s.commanded_on_s, 3.0 + 1.98 + 5.06, 1e-9);  // 10.04 s
  EXPECT_EQ(s.commanded_switches, 6);
  EXPECT_GE(s.shortest_on_s(), f.min_on_s - 1e-9);
  EXPECT_GE(s.shortest_off_s(), f.min_off_s - 1e-9);
  // The same spells as flags: the pump decides alone and bridges the first gap.
  std::vector<char> flags(t.size(), 0);
  for (std::size_t i = 0; i < t.size(); ++i)
    for (std::size_t k = 0; k < on.size(); ++k) flags[i] = flags[i] || (t[i] > on[k] && t[i] < off[k]);
  const FlowSchedule alone = flow_schedule(t, flags, f);
  EXPECT_NEAR(alone.commanded_on_s, s.commanded_on_s, 1e-9);
  EXPECT_EQ(alone.on_s.size(), 2u);
  EXPECT_GT(alone.bridged_s, 1.9);
  // A short spell grows into the slack it has: 0.1 s before it (a 2.1 s gap), 1 s after it. The
  // pump's own rule (about its middle) would cut the spell before it instead.
  expect_spells(program_schedule({1.01, 6.11, 10.61}, {4.01, 7.61, 15.01}, t, f),
                {{1.01, 4.01}, {6.01, 8.01}, {10.61, 15.01}});
  // ... but not into a joint move ([8.4, 9.0] s; its ramp keeps the flow off from 7.89 s): the
  // spell ends clear of it, and nothing flows in the move.
  std::vector<char> blocked(t.size(), 0);
  for (int i = 420; i <= 450; ++i) blocked[static_cast<std::size_t>(i)] = 1;
  const FlowSchedule clear = program_schedule({1.01, 6.01, 10.61}, {4.01, 7.51, 15.01}, t, f, blocked);
  for (std::size_t k = 0; k < clear.on_s.size(); ++k)
    EXPECT_TRUE(clear.off_s[k] <= 7.89 + 1e-9 || clear.on_s[k] >= 9.51 - 1e-9) << "spell " << k;
  for (int i = 420; i <= 450; ++i) EXPECT_EQ(clear.flow_at(t[static_cast<std::size_t>(i)]), 0.0) << i;
  // A program within the minimums runs as it is.
  expect_spells(program_schedule({1.01, 6.01}, {4.01, 9.01}, t, f), {{1.01, 4.01}, {6.01, 9.01}});
  // Random programs: never shorter than the minimums, whatever their spells.
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> len(0.3, 4.0);
  for (int trial = 0; trial < 30; ++trial) {
    std::vector<double> a, b;
    for (double x = len(rng); x < 25.0;) {
      a.push_back(x), b.push_back(x + len(rng));
      x = b.back() + len(rng);
    }
    const FlowSchedule r = program_schedule(a, b, t, f);
    if (r.on_s.size() > 1) EXPECT_GE(r.shortest_off_s(), f.min_off_s - 1e-9) << trial;
    if (!r.on_s.empty()) EXPECT_GE(r.shortest_on_s(), f.min_on_s - 1e-9) << trial;
    EXPECT_NEAR(r.on_time_s(), r.commanded_on_s + r.bridged_s + r.extended_s - r.dropped_s - r.trimmed_s, 1e-9);
  }
}

TEST(FlowSchedule, AMalformedProgramIsAnError) {
  const std::vector<double> t = times(101, 0.1);
  const FlowConfig f = flow(0.5, 1.0, 1.0);
  EXPECT_THROW(program_schedule({1.0}, {}, t, f), std::invalid_argument);                    // sizes
  EXPECT_THROW(program_schedule({2.0}, {1.0}, t, f), std::invalid_argument);                 // empty spell
  EXPECT_THROW(program_schedule({1.0, 2.5}, {3.0, 4.0}, t, f), std::invalid_argument);       // overlapping
  EXPECT_THROW(program_schedule({std::nan("")}, {3.0}, t, f), std::invalid_argument);        // NaN
  EXPECT_THROW(program_schedule({1.0}, {12.0}, t, f), std::invalid_argument);                // past the samples
  EXPECT_THROW(program_schedule({1.0}, {3.0}, t, flow(2.0, 1.0, 3.0)), std::invalid_argument);  // config
  try {
    program_schedule({1.0, 2.5}, {3.0, 4.0}, t, f);
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("spell 1"), std::string::npos) << e.what();
  }
}

namespace {

// A trajectory through the samples of a region as the planner times it (region_spray), the time
// between two samples off the passes stretched by join_stretch (the arm easing its turns).
TimedTrajectory region_trajectory(const RegionSpray& rs, double join_stretch) {
  TimedTrajectory tr;
  double t = 0.0;
  for (std::size_t k = 0; k < rs.t_s.size(); ++k) {
    if (k > 0) {
      const bool join = rs.pass_index[k] < 0 && rs.pass_index[k - 1] < 0;
      t += (rs.t_s[k] - rs.t_s[k - 1]) * (join ? join_stretch : 1.0);
    }
    tr.t_s.push_back(t), tr.nozzle.push_back(rs.nozzle[k]), tr.spraying.push_back(rs.spraying[k]);
    tr.pass_index.push_back(rs.pass_index[k]), tr.region_index.push_back(0);
    tr.kind.push_back(static_cast<char>(rs.blocked[k] ? SegmentKind::Transit : rs.pass_index[k] >= 0 ? SegmentKind::Pass : SegmentKind::Link));
  }
  tr.duration_s = t;
  return tr;
}

// The nozzle position at time t along the samples (linear between them).
Eigen::Vector3d position_at(const std::vector<double>& t_s, const std::vector<NozzlePose>& nozzle, double t) {
  const auto it = std::lower_bound(t_s.begin(), t_s.end(), t);
  if (it == t_s.begin()) return nozzle.front().position_m;
  if (it == t_s.end()) return nozzle.back().position_m;
  const auto i = static_cast<std::size_t>(it - t_s.begin());
  const double u = (t - t_s[i - 1]) / (t_s[i] - t_s[i - 1]);
  return (1.0 - u) * nozzle[i - 1].position_m + u * nozzle[i].position_m;
}

}  // namespace

// The pump runs the plan's program on the arm's timing. A serpentine of three passes whose turns
// the planner sprays through (shorter than flow.min_off_s, 5 s here): on the planner's own timing
// the program is the planner's schedule and the executed deposit is the planner's, to rounding;
// with the turns 2.5 times slower (longer than 5 s) the program still sprays through them, every
// switch at the place the planner put it, where a pump deciding on the flags alone switches off.
TEST(ExecutedDeposit, ThePumpRunsThePlansProgramOnTheArmsTiming) {
  Config cfg;
  cfg.flow = flow(1.0, 1.0, 5.0);
  const Surface surface = test::analytic_bay([](double, double) { return 0.05; }, cfg, 0.95, 1.45, 0.8, 2);
  Plan plan;
  plan.rounds.emplace_back();
  plan.rounds[0].regions.emplace_back();
  std::vector<Pass>& passes = plan.rounds[0].regions[0].passes;
  passes = test::axial_region(3, 0.6, 0.25, 0.1, 1.15, {0.1}, 5.6 - cfg.planner.standoff_m, 5.6);
  const RegionSpray rs = region_spray(passes, cfg);
  ASSERT_EQ(rs.flow.on_s.size(), 1u) << "the planner sprays through both turns";
  ASSERT_GT(rs.flow.bridged_s, 0.0);

  // The planner's own timing.
  const TimedTrajectory same = region_trajectory(rs, 1.0);
  const PumpProgram p1 = planned_pump_program(plan, same, cfg);
  ASSERT_EQ(p1.on_s.size(), 1u);
  EXPECT_NEAR(p1.on_s[0], rs.flow.on_s[0], 1e-9);
  EXPECT_NEAR(p1.off_s[0], rs.flow.off_s[0], 1e-9);
  const ExecutedDeposit ex1 = execute_deposit(surface, plan, same, cfg);
  SprayedWall wall = unsprayed_wall(surface, cfg.profile.max_deviation_m);
  Eigen::VectorXd planned = Eigen::VectorXd::Zero(wall.surface.cloud.size());
  accumulate_dwells(spot_model_from_config(cfg.deposition), SurfaceIndex(wall.surface.cloud, 0.05), rs.nozzle, rs.dwell_s,
                    cfg.deposition.rebound_fraction, planned);
  ASSERT_GT(planned.maxCoeff(), 0.005);
  EXPECT_LT((ex1.deposited_m - planned).cwiseAbs().maxCoeff(), 1e-9 * planned.maxCoeff());

  // The turns eased: 2.5 times as long.
  const TimedTrajectory slow = region_trajectory(rs, 2.5);
  const PumpProgram p2 = planned_pump_program(plan, slow, cfg);
  ASSERT_EQ(p2.on_s.size(), 1u);
  for (auto [t_plan, t_arm] : {std::pair{rs.flow.on_s[0], p2.on_s[0]}, std::pair{rs.flow.off_s[0], p2.off_s[0]}})
    EXPECT_LT((position_at(rs.t_s, rs.nozzle, t_plan) - position_at(slow.t_s, slow.nozzle, t_arm)).norm(), 1e-3);
  const ExecutedDeposit ex2 = execute_deposit(surface, plan, slow, cfg);
  EXPECT_EQ(ex2.flow.on_s.size(), 1u);
  EXPECT_NEAR(ex2.flow.bridged_s, 0.0, 1e-9);  // nothing the program did not ask for
  EXPECT_GT(ex2.flow.on_time_s(), rs.flow.on_time_s() + 1.0);  // the slower turns, sprayed
  // The pump on the trajectory's flags alone: off over both turns.
  const ExecutedDeposit alone = execute_deposit(surface, std::vector<int>{1}, slow, cfg);
  EXPECT_EQ(alone.flow.on_s.size(), 3u);

  // A trajectory that is not the plan's is an error naming the region.
  TimedTrajectory other = same;
  other.region_index.back() = 1;
  EXPECT_THROW(planned_pump_program(plan, other, cfg), std::invalid_argument);
  other = same;
  for (auto& p : other.pass_index)
    if (p == 2) p = 3;
  EXPECT_THROW(planned_pump_program(plan, other, cfg), std::invalid_argument);
  other = same;
  for (auto& p : other.pass_index) p = p == 0 ? 1 : p == 1 ? 0 : p;  // passes out of order
  EXPECT_THROW(planned_pump_program(plan, other, cfg), std::invalid_argument);
}

// SpotOnGridBound settles spot_miss_fraction's zeros without casting rays: wherever it answers
// "surely on the grid", the 128 rays find no miss (checked ray by ray, through spot_miss_fraction),
// over random nozzle poses in front of a slice with a TD of -80..+200 mm and a hole, at standoffs
// of 0.5-1.6 m, tilted up to 34 deg along and around the axis; and it does answer for most poses
// whose spot lies well inside the slice (else it would save nothing). A section profile gets no
// answer.
TEST(ExecutedDeposit, SpotOnGridBoundOnlyAnswersWhereNoRayMisses) {
  Config cfg;
  const test::TdFunction td = [](double d, double theta) {
    if (std::hypot(d - 1.1, theta - 1.45) < 0.03) return std::numeric_limits<double>::quiet_NaN();  // a hole
    return 0.08 + 0.12 * std::sin(3.0 * d) * std::cos(5.0 * theta) - 0.04 * (theta > 1.3);
  };
  const Surface s = test::analytic_bay(td, cfg, 0.8, 2.0, 2.4, 2);
  const SpotModel model = spot_model_from_config(cfg.deposition);
  const Grid& g = s.grid;
  const SpotOnGridBound bound(model, g);
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double R = cfg.profile.design_radius_m;
  int answered = 0, interior = 0, interior_answered = 0, missing = 0;
  for (int k = 0; k < 4000; ++k) {
    const double theta = 0.7 + 1.4 * u(rng), d = -0.2 + 2.8 * u(rng), standoff = 0.5 + 1.1 * u(rng);
    const double tilt_d = (u(rng) - 0.5) * 1.2, tilt_t = (u(rng) - 0.5) * 1.2;  // +-0.6 rad
    NozzlePose p;
    const Eigen::Vector3d radial(0, std::cos(theta), std::sin(theta)), along(1, 0, 0),
        around(0, -std::sin(theta), std::cos(theta));
    p.position_m = Eigen::Vector3d(d, 0, 0) + (R - standoff) * radial;
    p.axis = (radial + std::tan(tilt_d) * along + std::tan(tilt_t) * around).normalized();
    const bool sure = bound.surely_on_grid(p);
    const double miss = spot_miss_fraction(model, g, p);
    if (miss > 0.0) ++missing;
    if (sure) {
      ++answered;
      ASSERT_EQ(miss, 0.0) << "pose " << k << " d " << d << " theta " << theta << " standoff " << standoff;
    }
    const bool well_inside = d > 0.6 && d < 1.8 && theta > 1.05 && theta < 1.75 && std::abs(tilt_d) < 0.3 &&
                             std::abs(tilt_t) < 0.3 && std::hypot(d - 1.1, theta - 1.45) > 0.25;
    if (well_inside) ++interior, interior_answered += sure;
  }
  std::printf("bound answered %d of 4000 poses (%d of %d well inside); %d poses miss some rays\n", answered,
              interior_answered, interior, missing);
  EXPECT_GT(missing, 1000);  // the poses reach past the slice and into the hole
  EXPECT_GT(interior, 100);
  EXPECT_GT(interior_answered, 0.8 * interior);
  // A section design line: no answer.
  Grid section = g;
  section.profile = DesignProfile::circle(R);
  section.profile.polyline_m = {Eigen::Vector2d(R, 0.0), Eigen::Vector2d(0.0, R)};
  NozzlePose centre;
  centre.position_m = Eigen::Vector3d(1.2, 0, 0) + (R - 1.0) * Eigen::Vector3d(0, std::cos(1.4), std::sin(1.4));
  centre.axis = Eigen::Vector3d(0, std::cos(1.4), std::sin(1.4));
  EXPECT_TRUE(bound.surely_on_grid(centre));
  EXPECT_FALSE(SpotOnGridBound(model, section).surely_on_grid(centre));
}
