// Speed profiles: the paper's start/end profiles against their closed forms integrated
// numerically, derivatives, quintic boundary conditions.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>

#include "shotcrete/timing/speed_profile.hpp"
#include "timing_fixtures.hpp"

using namespace shotcrete;

using shotcrete::test::kPi;

namespace {

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
