#pragma once
// Transits by the seed method (key points and optimal space allowance): every rest-to-rest joint
// move of a trajectory is checked sample by sample against the wall and the arm itself; one that
// comes closer than the margins is re-routed through a posture of maximum space allowance, with
// rest-to-rest joint quintics start -> via -> goal.
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
                                   // replaced it (still a failure)
  std::string reason;              // why not, when not rerouted
  std::vector<Eigen::VectorXd> vias;      // the postures passed through, in order
  std::vector<double> via_allowance_m;    // posture_allowance of each (>= 0)
  double min_allowance_m = 0.0;    // least distance less margin along the new move (check_clearance_octree;
                                   // >= 0 when rerouted, < 0 when eased)
  double straight_duration_s = 0.0, duration_s = 0.0;  // of the move before and after
  int optimisations = 0;           // via postures searched (BOBYQA runs)
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
/// (replace_joint_move). When no single via does, each leg is re-routed once more the same way.
/// A move whose start or goal posture already breaks a margin (the region's own posture), or
/// that no route clears, stays as it was and is counted in `failed` with the reason. The shapes no
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

}  // namespace shotcrete
