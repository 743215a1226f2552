#pragma once
// Speed profiles along a path (docs/architecture.md §8, seed paper on AIWCPSO for shotcrete arms):
// cycloidal and quintic speed changes, the paper's start / end profiles and rest-to-rest moves.
#include <vector>

namespace shotcrete {

/// Shape of a speed change v0 -> v1 over T: v = v0 + (v1 - v0) g(t / T).
/// Cycloid: g = tau - sin(2 pi tau) / (2 pi) (the paper's (m - sin m) / (2 pi), acceleration
/// 1 - cos: starts and ends at zero). Quintic: g = 10 tau^3 - 15 tau^4 + 6 tau^5 (acceleration and
/// jerk zero at both ends). Both cover (v0 + v1) / 2 * T.
enum class SpeedShape { Cycloid, Quintic };

struct SpeedPiece {
  double v0_mps = 0.0;
  double v1_mps = 0.0;
  double duration_s = 0.0;
  SpeedShape shape = SpeedShape::Cycloid;

  double length_m() const { return 0.5 * (v0_mps + v1_mps) * duration_s; }
  double speed_at(double t_s) const;     // t in [0, duration]
  double accel_at(double t_s) const;     // dv/dt
  double jerk_at(double t_s) const;      // d2v/dt2
  double distance_at(double t_s) const;  // distance covered since the piece start
  double peak_accel_mps2() const;        // |v1 - v0| / T * max g'
};

/// Speed along a path: pieces one after the other, starting at arc length 0.
class SpeedProfile {
 public:
  struct State {
    double s_m = 0.0, v_mps = 0.0, a_mps2 = 0.0, j_mps3 = 0.0;
  };
  void append(const SpeedPiece& piece);  // zero-duration pieces are dropped
  void append(const SpeedProfile& other);
  double duration_s() const { return t_.empty() ? 0.0 : t_.back(); }
  double length_m() const { return s_.empty() ? 0.0 : s_.back(); }
  State at(double t_s) const;  // clamped to [0, duration]
  /// Time at which arc length s is reached (bisection inside the piece).
  double time_at_distance(double s_m) const;
  const std::vector<SpeedPiece>& pieces() const { return pieces_; }

 private:
  std::vector<SpeedPiece> pieces_;
  std::vector<double> t_{0.0}, s_{0.0};  // cumulative start time / arc length of each piece + end
};

/// Paper start profile over s_start: cycloidal acceleration 0 -> v over t1 = k1 Ts, then cruise
/// until Ts = 2 s_start / (v (2 - k1)).
SpeedProfile cycloid_start(double s_start_m, double v_mps, double k1);
/// Paper end profile over s_end: cruise until t2 = k2 Te, then cycloidal deceleration v -> 0 until
/// Te = 2 s_end / (v (1 + k2)).
SpeedProfile cycloid_end(double s_end_m, double v_mps, double k2);
/// Rest-to-rest move over length_m: accelerate 0 -> v over accel_time_s, cruise, decelerate over
/// accel_time_s (quintic: the baseline). When the move is too short to reach v the peak speed
/// drops to length / accel_time.
SpeedProfile rest_to_rest(double length_m, double v_mps, double accel_time_s, SpeedShape shape);

}  // namespace shotcrete
