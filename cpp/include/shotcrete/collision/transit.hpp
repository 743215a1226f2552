#pragma once
// Transits by the seed method (key points and optimal space allowance): every rest-to-rest joint
// move of a trajectory is checked sample by sample against the wall and the arm itself; one that
// comes closer than the margins is re-routed through a posture of maximum space allowance, with
// rest-to-rest joint quintics start -> via -> goal.
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "shotcrete/collision/clearance.hpp"
#include "shotcrete/config.hpp"

namespace shotcrete {

class Robot;
struct TimedTrajectory;

/// Space allowance of posture q: the least distance of a link shape to the wall less its margin
/// and of a checked link pair (self_check_pairs) less self_margin_m, over every shape and pair;
/// negative when a margin is broken. Distances are read up to at most margin + cap_m (the answer
/// is then at most cap_m), which keeps the octree queries cheap. With `fixed` (fixed_shapes), the
/// shapes no posture moves are left out: what a choice of posture can change.
double posture_allowance(const Robot& robot, const Eigen::VectorXd& q, const WallOctree& wall,
                         const ClearanceConfig& config, const std::vector<std::pair<int, int>>& pairs, double cap_m,
                         const std::vector<char>* fixed = nullptr);

/// One joint move that came closer than the margins.
struct TransitDetour {
  int move = 0;                    // index among the trajectory's joint moves (joint_moves: 0 = from the start)
  int region_index = -1;           // -1 between regions, else a stop-and-go move inside that region
  double start_time_s = 0.0;       // in the final trajectory
  int straight_samples_below = 0;  // link-samples below a margin on the straight joint interpolation
  std::string straight_worst;      // the link (or link pair) that came closest, and how close [m]
  double straight_min_allowance_m = 0.0;  // least distance less margin on it (< 0)
  bool rerouted = false;           // a clear route was found and replaced the move
  bool eased = false;              // no clear route, but one with at most half the straight move's
                                   // link-samples below a margin (or fewer, 0.1 m less short of them)
                                   // replaced it; or, from or to a posture itself short of the
                                   // margins, one routed with the margins lowered by its shortfall
                                   // that breaks them at fewer samples (still a failure)
  std::string reason;              // why not, when not rerouted
  std::vector<Eigen::VectorXd> vias;      // the postures passed through, in order
  std::vector<double> via_allowance_m;    // posture_allowance of each (>= 0 when rerouted)
  double min_allowance_m = 0.0;    // least distance less margin along the new move (check_clearance_octree;
                                   // >= 0 when rerouted, < 0 when eased)
  double straight_duration_s = 0.0, duration_s = 0.0;  // of the move before and after
  int optimisations = 0;           // via postures searched (BOBYQA runs)
  int sampled_nodes = 0;           // postures the sampled planner (RRT-Connect) added, when the via routes failed
};

struct TransitReport {
  int moves_checked = 0;           // joint moves of the trajectory (transits and stop-and-go moves)
  int rerouted = 0, failed = 0;
  double detour_time_s = 0.0;      // duration added by the re-routes (sum over the moves)
  std::vector<TransitDetour> detours;  // the moves that came closer than the margins, in time order
  double seconds = 0.0;
};

/// Checks every joint move of `trajectory` (joint_moves) with check_clearance_octree; each that comes
/// closer than a margin is re-routed: postures of maximum space allowance (BOBYQA within the joint
/// limits on posture_allowance, saturated at config.via_allowance_m so that, once every shape has
/// that much, the posture nearest the straight move's midpoint wins) are sought from several starts
/// (the move's midpoint, the midpoint with the telescopes in, a quarter and three quarters along
/// it, the stow posture); the shortest route start -> via -> goal of rest-to-rest quintics
/// (joint_move_through) whose every sample keeps the margins replaces the move
/// (replace_joint_move). When no single via does, each leg is re-routed once more the same way;
/// when that fails too, a joint-space RRT-Connect (Router::sampled_route, seeded per move) looks
/// for a path whose postures keep the margins, shortened greedily, its postures the vias.
/// A move whose start or goal posture already breaks a margin (the region's own posture) is
/// routed the same way with every margin lowered by that shortfall (and a leaf diagonal), and by
/// the sampled planner with the margins proper but near a short end; of those routes, the ones that
/// break the margins proper at fewer link-samples (at most half, 0.1 m less short, or in no more
/// time) may replace it, the one with the fewest does (`eased`); a move no route clears is replaced by the best route tried by the
/// same rule (`eased`), else stays as it was. Either way it is counted in `failed` with the
/// reason. The detours' times are those before plan_for_arm's slowing after them. The shapes no
/// posture moves (fixed_shapes: the base) are left out of every judgement here (a base too close
/// to the wall is the base's place, not a move's: the clearance check reports it, LinkClearance::fixed).
TransitReport clear_transits(const Robot& robot, TimedTrajectory& trajectory, const WallOctree& wall,
                             const ClearanceConfig& config, const TimingConfig& timing);

/// The posture a job starts from (the trajectory's first sample).
struct StartPosture {
  Eigen::VectorXd q;                   // the posture
  Eigen::VectorXd preferred;           // the posture asked for (the robot's stow)
  bool moved = false;                  // q is not `preferred`: that one broke a margin and q keeps them
  double preferred_allowance_m = 0.0;  // posture_allowance of `preferred` (read up to 10 m)
  double allowance_m = 0.0;            // posture_allowance of q (read up to 10 m); < 0: no clear posture found
  int optimisations = 0;               // postures searched (BOBYQA runs)
};

/// `preferred` when it keeps every margin from `wall` (posture_allowance >= 0, without the fixed shapes). Else the posture
/// nearest it with room: the transit router's search (maximum space allowance saturated at
/// config.via_allowance_m, then three times it, then unsaturated, with a pull toward `preferred`)
/// from `preferred`, from it with the telescopes in, from the neutral posture and from each of
/// them turned about the first joint by a quarter and a half turn; of the postures that keep the
/// margins, the nearest to `preferred` (joint distance normalised by the ranges). When none does,
/// q stays `preferred` (moved false, allowance_m < 0): the clearance check then reports it.
StartPosture start_posture(const Robot& robot, const Eigen::VectorXd& preferred, const WallOctree& wall,
                           const ClearanceConfig& config);

/// Swing room used by place_base: the slew directions are tried every kSwingStepRad (15 deg), a
/// posture with room within kSwingRoomSlack_m of the cap counts as roomy (BOBYQA's tolerance).
constexpr double kSwingStepRad = 0.2617993877991494;
constexpr double kSwingRoomSlack_m = 0.01;
/// Places place_base tries lie this far apart along the axis [m]; the way between two is checked
/// every kBaseWayStep_m; a shift past kMaxBaseShift_m is refused (robot.max_base_shift_m's range).
constexpr double kBaseShiftStep_m = 0.1;
constexpr double kBaseWayStep_m = 0.05;
constexpr double kMaxBaseShift_m = 20.0;

/// How much room the arm has to slew all the way round (swing_room).
struct SwingRoom {
  double least_m = 0.0;         // over the slew directions, the most posture_allowance (without the fixed shapes) a posture has there, capped at via_allowance_m
  double worst_slew_rad = 0.0;  // the direction with the least
  Eigen::VectorXd worst_q;      // the roomiest posture found there
  int directions = 0;           // slew directions measured (fewer when it stopped below stop_below_m)
  int optimisations = 0;        // postures searched (BOBYQA runs)
};

/// At every slew direction (multiples of step_rad within the first joint's range, and its limits), the posture of most
/// space allowance with the slew held there (the transit router's search, saturated at
/// config.via_allowance_m, from the roomiest posture of the direction before, the stow and the
/// neutral postures and both with the telescopes in); the least of those. An arm with
/// via_allowance_m everywhere can turn from any spraying side to any other through a via posture:
/// the joint moves between its posture families have somewhere to go. Stops at the first
/// direction below stop_below_m; the directions nearest first_rad (when finite) are measured first.
SwingRoom swing_room(const Robot& robot, const WallOctree& wall, const ClearanceConfig& config,
                     double step_rad = kSwingStepRad, double stop_below_m = -std::numeric_limits<double>::infinity(),
                     double first_rad = std::numeric_limits<double>::quiet_NaN());

/// The least distance of the shapes no joint moves (fixed_shapes: the base, the turret) to `wall`
/// less config.base_margin_m (exact distances); < 0: the base stands in something the scan holds.
double base_room(const Robot& robot, const WallOctree& wall, const ClearanceConfig& config);

/// Where the job places the arm's base (robot.place_base).
struct BasePlacement {
  bool checked = false;  // the placement was measured (robot.place_base, clearance.enabled, a scan)
  Eigen::Vector3d configured_m = Eigen::Vector3d::Zero();  // robot.base_position_m
  Eigen::Vector3d position_m = Eigen::Vector3d::Zero();    // where the job places it
  double shift_m = 0.0;          // along the tunnel axis (ex) from configured_m [m]
  bool moved = false;            // position_m is not configured_m
  bool found = false;            // position_m has room to slew every way (or the placement was not checked)
  double configured_room_m = 0.0;       // swing_room's least at the configured place, up to its first direction short of room (from slew 0 outward) [m]
  double configured_short_slew_rad = 0.0;  // ... and that direction (the last measured when none is short)
  double configured_base_room_m = 0.0;  // base_room there [m]
  double room_m = 0.0, base_room_m = 0.0;  // the same at position_m
  int places_tried = 0;
  double seconds = 0.0;
};

/// The configured base (robot's) when the arm has room there to slew every way (swing_room's least
/// at least config.via_allowance_m) and its fixed links keep base_margin_m (base_room); else the
/// nearest place along `along` (the tunnel axis) within max_shift_m, in steps of kBaseShiftStep_m,
/// that has both, away from the direction short of room first, never carrying the base's fixed
/// links through a point of `wall` (a face, a rig's carrier: the way is checked every
/// kBaseWayStep_m). A rig stands as far from the face as its boom needs to fold over and turn: a
/// base mid-bay 0.6 m from a face joins its two slew families only through the face. None found,
/// or a robot without fixed collision shapes (nothing tells where it can stand): the configured
/// place (found false when it lacks room). Throws std::invalid_argument for an axis that is not a
/// vector or max_shift_m outside 0..kMaxBaseShift_m.
BasePlacement place_base(const Robot& robot, const WallOctree& wall, const Eigen::Vector3d& along,
                         const ClearanceConfig& config, double max_shift_m);

}  // namespace shotcrete
