#pragma once
// Cartesian nozzle paths (docs/architecture.md §8): pieces (polylines or half circles) one after the
// other, and the half-circle turn-around between two passes of a serpentine.
#include <Eigen/Core>
#include <cstddef>
#include <vector>

#include "shotcrete/deposition/deposition.hpp"  // NozzlePose

namespace shotcrete {

enum class SegmentKind : char { Pass = 0, Turn = 1, Lead = 2, Link = 3, Transit = 4 };

/// How the speed profile treats a path piece (region_profile).
enum class PieceMotion : char {
  ByKind = 0,         // by its kind: cruise on passes, leads and links, speed changes on turns
  StopAtEnd = 1,      // stop-and-go run-out: cycloidal stop at its end (cycloid end, k2 = 0)
  RestToRest = 2,     // stop-and-go middle: rest to rest, cruising at speed_mps (a joint move in time_plan)
  StartFromRest = 3,  // stop-and-go run-in: cycloidal start from rest (cycloid start, k1 = 1)
  SprayOffGap = 4,    // spray-off gap on a pass line: cycloidal change from speed_mps to speed_out_mps
  Creep = 5,          // tight turn's middle: rest to rest along the path (tracked, not a joint move), slow
                      // enough that the turn lasts the pump's off spell (min_turn_s)
};

/// One geometric piece of a nozzle path: a polyline of poses or a half circle.
struct PathPiece {
  SegmentKind kind = SegmentKind::Pass;
  int pass_index = -1;    // global pass number for kind == Pass, else -1
  bool spraying = false;
  double speed_mps = 0.0; // planned cruise speed (pass, lead, link); turn: speed at its start
  double speed_out_mps = 0.0;  // turn and spray-off gap: speed at its end (next pass); others = speed_mps
  PieceMotion motion = PieceMotion::ByKind;
  // polyline
  std::vector<NozzlePose> poses;
  std::vector<double> cum_m;  // arc length at each pose, from 0
  // arc: p(phi) = center + r (-cos(phi) u + sin(phi) d), phi in [0, pi]; the axis blends from
  // axis0 to axis1 with weight (1 - cos phi) / 2
  bool is_arc = false;
  double accel_scale = 1.0;  // turn arc (and a tight turn's creep): share of the profile's turn
                             // acceleration that caps its speed (region_path's gap scale: time_plan
                             // eases awkward joins)
  Eigen::Vector3d center{0, 0, 0}, u{1, 0, 0}, d{0, 1, 0};
  double radius_m = 0.0;
  Eigen::Vector3d axis0{0, 0, 1}, axis1{0, 0, 1};
  // pass with a per-waypoint speed profile (Pass::speed_profile_mps): its constant-speed runs
  std::vector<double> run_len_m, run_speed_mps;

  double length_m() const;
  NozzlePose pose_at(double s_m) const;
  Eigen::Vector3d tangent_at(double s_m) const;
  double curvature_at(double s_m) const;  // 1/r on arcs, turning angle / step on polylines
};

class CartesianPath {
 public:
  void append(PathPiece piece);
  const std::vector<PathPiece>& pieces() const { return pieces_; }
  double length_m() const { return cum_.back(); }
  double piece_start_m(std::size_t i) const { return cum_[i]; }
  /// Piece containing arc length s and the local arc length inside it.
  std::size_t locate(double s_m, double& local_m) const;
  NozzlePose pose_at(double s_m) const;
  Eigen::Vector3d tangent_at(double s_m) const;
  double curvature_at(double s_m) const;

 private:
  std::vector<PathPiece> pieces_;
  std::vector<double> cum_{0.0};
};

/// Speeds, spraying and the straight runs of a turn-around.
struct TurnAroundOptions {
  double speed_in_mps = 0.0;   // at the end of pass a (the run-out and the arc start)
  double speed_out_mps = 0.0;  // at the start of pass b (the arc end and the run-in)
  bool spraying = false;
  double run_out_m = 0.0;  // > 0: straight run of that length before the arc
  double run_in_m = -1.0;  // straight run after the arc; < 0: run_out_m
  Eigen::Vector3d dir_b_start = Eigen::Vector3d::Zero();  // pass b's start direction; zero: -dir_a
  // Turn of the spray axis per metre at pass a's end and pass b's start (rotation vectors, along
  // the travel): the runs carry it down to 0 at the arc (a leaning nozzle's axis turns on the passes).
  Eigen::Vector3d axis_rate_a = Eigen::Vector3d::Zero(), axis_rate_b = Eigen::Vector3d::Zero();
};

/// Half circle from the end of pass a (position pa, unit direction da) to the start of pass b:
/// the pass ends are first aligned along da by a straight extension (the "line" of line + arc),
/// then joined by a half circle whose diameter is their distance across (the pass spacing).
/// Returns 1 to 3 pieces (extension of a, arc, extension before b), kinds Link / Turn.
/// The runs before and after the arc carry the speed change to and from the turn speed, so the arc
/// is entered at the turn speed. When dir_b_start is not exactly -dir_a the run-in is a cubic
/// Bezier tangent to the arc and to the pass, so the path has no corner. The runs carry the axis
/// turns axis_rate_a / _b down to 0, and the arc blends the axis between the runs' far ends.
std::vector<PathPiece> turn_around(const NozzlePose& end_a, const Eigen::Vector3d& dir_a, const NozzlePose& start_b,
                                   const TurnAroundOptions& options);

}  // namespace shotcrete
