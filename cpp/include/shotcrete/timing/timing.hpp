#pragma once
// Motion timing (docs/architecture.md §8, seed paper on AIWCPSO for shotcrete arms), all of it: include
// the piece you need instead where you can.
//   speed_profile.hpp   cycloidal / quintic speed changes, the paper's start and end profiles
//   cartesian_path.hpp  path pieces, the path, the half-circle turn-around
//   region_path.hpp     the path of a region (leads, passes, joins), its speed profile, the baseline
//   sampling.hpp        samples at a fixed rate, spray dwells, the nozzle limit check
//   trajectory.hpp      joint quintics and the timed joint trajectory of regions in order
//   pso.hpp             the particle swarm (AIWCPSO)
//   tuning.hpp          the region joint model and the swarm's tuning of the timing parameters
// The joint tracking the timing relies on (track_joint_path, joint_speed_limits, arm_speed_caps)
// lives with the robot: shotcrete/robot/joint_tracking.hpp.
#include "shotcrete/robot/joint_tracking.hpp"
#include "shotcrete/timing/cartesian_path.hpp"
#include "shotcrete/timing/pso.hpp"
#include "shotcrete/timing/region_path.hpp"
#include "shotcrete/timing/sampling.hpp"
#include "shotcrete/timing/speed_profile.hpp"
#include "shotcrete/timing/trajectory.hpp"
#include "shotcrete/timing/tuning.hpp"
