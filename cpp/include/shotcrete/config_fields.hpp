#pragma once
// The field table of the configuration: name, member pointer, allowed range, unit/doc.
// One table drives YAML loading and dumping, validation, the Python properties and the ROS
// parameter overrides, so a key exists in exactly one place.
#include <limits>

#include "shotcrete/config.hpp"

namespace shotcrete::fields {

constexpr double kInf = std::numeric_limits<double>::infinity();

// f(name, member pointer, min, max, doc); min/max are ignored for bool, string, vector and enum
// fields. An enum field is read and written by the names of its enum_names table (types.hpp):
// YAML, Python and ROS parameters all take text, and an unknown name is an error listing them.
template <class F> void visit(IoConfig*, F&& f) {
  f("max_extent_m", &IoConfig::max_extent_m, 1.0, 1e6, "largest accepted cloud extent [m]");
  f("unit_scale", &IoConfig::unit_scale, 1e-6, 1e3, "factor applied to input coordinates (0.001 for mm)");
}
template <class F> void visit(PreprocessConfig*, F&& f) {
  f("crop_enabled", &PreprocessConfig::crop_enabled, 0, 0, "apply the crop box");
  f("crop_min_m", &PreprocessConfig::crop_min_m, 0, 0, "crop box minimum corner [m]");
  f("crop_max_m", &PreprocessConfig::crop_max_m, 0, 0, "crop box maximum corner [m]");
  f("voxel_size_m", &PreprocessConfig::voxel_size_m, 0.0, 1.0, "voxel edge [m]; 0 = off");
  f("outlier_neighbors", &PreprocessConfig::outlier_neighbors, 0, 1000, "k of the outlier filter; 0 = off");
  f("outlier_std_ratio", &PreprocessConfig::outlier_std_ratio, 0.1, 100.0, "outlier threshold [std devs]");
}
template <class F> void visit(ProfileConfig*, F&& f) {
  f("design_radius_m", &ProfileConfig::design_radius_m, 0.5, 50.0, "design profile radius [m]");
  f("section_path", &ProfileConfig::section_path, 0, 0, "design cross-section CSV (y_m,z_m[,bulge]); empty = the circle of design_radius_m");
  f("axis_origin_m", &ProfileConfig::axis_origin_m, 0, 0, "a point on the tunnel axis [m]");
  f("axis_direction", &ProfileConfig::axis_direction, 0, 0, "axis direction (unit-free)");
  f("alignment_path", &ProfileConfig::alignment_path, 0, 0, "alignment CSV (chainage_m,x_m,y_m,z_m) giving the axis where the scan lies; empty = axis_origin_m/axis_direction");
  f("estimate_axis", &ProfileConfig::estimate_axis, 0, 0, "fit the axis to the cloud");
  f("estimate_axis_origin", &ProfileConfig::estimate_axis_origin, 0, 0, "with estimate_axis: fit the centre too (false: keep axis_origin_m)");
  f("min_fit_arc_rad", &ProfileConfig::min_fit_arc_rad, 0.05, 6.2832, "arc the wall must cover around a fitted axis [rad]");
  f("max_deviation_m", &ProfileConfig::max_deviation_m, 0.01, 10.0, "band around the design line kept for the grid [m]");
}
template <class F> void visit(NormalsConfig*, F&& f) {
  f("k_neighbors", &NormalsConfig::k_neighbors, 3, 500, "neighbours per normal");
}
template <class F> void visit(GridConfig*, F&& f) {
  f("cell_size_m", &GridConfig::cell_size_m, 0.005, 1.0, "cell edge along axis and arc [m]");
  f("min_points_per_cell", &GridConfig::min_points_per_cell, 1, 10000, "fewer points: cell empty");
  f("bay", &GridConfig::bay, 0, 0, "bay to grid along the axis: whole, range (bay_start_m..bay_end_m) or detect (the unlined stretch)");
  f("bay_start_m", &GridConfig::bay_start_m, -1e6, 1e6, "bay: range; start chainage along the axis from profile.axis_origin_m [m]");
  f("bay_end_m", &GridConfig::bay_end_m, -1e6, 1e6, "bay: range; end chainage [m]");
  f("lined_td_m", &GridConfig::lined_td_m, 0.001, 1.0, "bay: detect; a cell within this TD of the design line looks lined [m]");
  f("lined_fraction", &GridConfig::lined_fraction, 0.5, 1.0, "bay: detect; share of lined cells that makes a cross-section lining");
  f("max_normal_tilt_rad", &GridConfig::max_normal_tilt_rad, 0.1, 1.5708, "points with normals farther than this from radial are not wall [rad]");
  f("obstacle_gap_m", &GridConfig::obstacle_gap_m, 0.0, 10.0, "wall-like points this far inside their cell's outermost surface are an obstacle (duct), not wall [m]; 0 = off");
}
template <class F> void visit(RegionConfig*, F&& f) {
  f("min_region_cells", &RegionConfig::min_region_cells, 1, 100000, "smaller regions merge");
}
template <class F> void visit(SynthConfig*, F&& f) {
  f("design_radius_m", &SynthConfig::design_radius_m, 0.5, 50.0, "design radius [m]");
  f("section_path", &SynthConfig::section_path, 0, 0, "design section CSV of the synthetic bay; empty = the circle");
  f("length_m", &SynthConfig::length_m, 0.1, 20.0, "bay length [m]");
  f("theta_min_rad", &SynthConfig::theta_min_rad, -1.5708, 4.7124, "first wall angle, from the right springline [rad]");
  f("theta_max_rad", &SynthConfig::theta_max_rad, -1.5708, 4.7124, "last wall angle [rad]");
  f("base_overbreak_m", &SynthConfig::base_overbreak_m, -1.0, 2.0, "uniform over-break [m]");
  f("pit_count", &SynthConfig::pit_count, 0, 100000, "number of dig pits");
  f("pit_depth_min_m", &SynthConfig::pit_depth_min_m, 0.0, 2.0, "smallest pit depth [m]");
  f("pit_depth_max_m", &SynthConfig::pit_depth_max_m, 0.0, 2.0, "largest pit depth [m]");
  f("pit_radius_min_m", &SynthConfig::pit_radius_min_m, 0.01, 10.0, "smallest pit radius [m]");
  f("pit_radius_max_m", &SynthConfig::pit_radius_max_m, 0.01, 10.0, "largest pit radius [m]");
  f("pit_shape_alpha", &SynthConfig::pit_shape_alpha, 0.1, 10.0, "pit shape exponent");
  f("noise_m", &SynthConfig::noise_m, 0.0, 0.1, "radial scanner noise std dev [m]");
  f("points_per_cell", &SynthConfig::points_per_cell, 0.1, 10000.0, "mean points per grid cell");
  f("seed", &SynthConfig::seed, 0, 0, "random seed");
  f("protrusion_height_m", &SynthConfig::protrusion_height_m, 0.0, 2.0, "rock protrusion toward the axis (0 = none) [m]");
  f("protrusion_d_m", &SynthConfig::protrusion_d_m, -10.0, 30.0, "protrusion centre along the bay [m]");
  f("protrusion_theta_rad", &SynthConfig::protrusion_theta_rad, -3.2, 3.2, "protrusion centre angle [rad]");
  f("protrusion_radius_m", &SynthConfig::protrusion_radius_m, 0.01, 10.0, "protrusion radius on the unrolled wall [m]");
  f("context_enabled", &SynthConfig::context_enabled, 0, 0, "add the unsprayed surroundings: previous bay, invert, face");
  f("context_previous_bay_m", &SynthConfig::context_previous_bay_m, 0.0, 20.0, "length of the lined previous bay (d < 0) [m]");
  f("context_invert_depth_m", &SynthConfig::context_invert_depth_m, 0.0, 10.0, "floor plane below the springlines [m]; 0 = none");
  f("context_face", &SynthConfig::context_face, 0, 0, "a face plane across the axis at d = length_m");
  f("context_duct_diameter_m", &SynthConfig::context_duct_diameter_m, 0.0, 5.0, "ventilation duct under the crown, from the lining to its outlet [m]; 0 = none");
  f("context_duct_gap_m", &SynthConfig::context_duct_gap_m, 0.0, 5.0, "gap between the design line and the duct's top [m]");
  f("context_duct_y_m", &SynthConfig::context_duct_y_m, -20.0, 20.0, "duct's centre across the axis (left positive) [m]");
  f("context_duct_outlet_d_m", &SynthConfig::context_duct_outlet_d_m, -1000.0, 1000.0,
    "duct's outlet along the axis (the bay runs from d = 0) [m]; past the bay's far end: over both bays");
  f("context_rig_length_m", &SynthConfig::context_rig_length_m, 0.0, 30.0, "rig carrier: a box on the invert behind the arm's base [m]; 0 = none");
  f("context_rig_width_m", &SynthConfig::context_rig_width_m, 0.1, 20.0, "rig carrier's width, centred across the axis [m]");
  f("context_rig_height_m", &SynthConfig::context_rig_height_m, 0.1, 10.0, "rig carrier's height above the invert [m]");
  f("context_rig_front_d_m", &SynthConfig::context_rig_front_d_m, -100.0, 100.0, "chainage of the rig carrier's front end [m]");
  f("context_muck_height_m", &SynthConfig::context_muck_height_m, 0.0, 10.0, "muck pile on the invert at the face: its height there [m]; 0 = none");
  f("context_muck_length_m", &SynthConfig::context_muck_length_m, 0.01, 50.0, "how far back from the face the muck pile reaches [m]");
  f("context_muck_width_m", &SynthConfig::context_muck_width_m, 0.01, 50.0, "the muck pile's width across at its foot [m]");
  f("context_scanner_shadow", &SynthConfig::context_scanner_shadow, 0, 0, "drop the points the scanner cannot see (behind the duct, the rig, the muck)");
  f("context_scanner_position_m", &SynthConfig::context_scanner_position_m, 0, 0, "the scanner (d along the axis, y across, z up) [m]");
  f("after_flow_scale", &SynthConfig::after_flow_scale, 0.1, 3.0, "after-scan: real / modelled flow");
  f("after_rebound_fraction", &SynthConfig::after_rebound_fraction, 0.0, 0.9, "after-scan: real rebound share");
  f("after_thickness_noise", &SynthConfig::after_thickness_noise, 0.0, 1.0, "after-scan: correlated layer noise, share of the layer (std dev)");
  f("after_noise_length_m", &SynthConfig::after_noise_length_m, 0.01, 100.0, "after-scan: correlation length of the layer noise [m]");
  f("after_noise_m", &SynthConfig::after_noise_m, 0.0, 0.1, "after-scan: scanner noise std dev [m]");
  f("after_points_per_cell", &SynthConfig::after_points_per_cell, 0.1, 10000.0, "after-scan: mean points per grid cell");
  f("after_pose_rpy_rad", &SynthConfig::after_pose_rpy_rad, 0, 0, "after-scan pose in the before frame: roll, pitch, yaw [rad]");
  f("after_pose_translation_m", &SynthConfig::after_pose_translation_m, 0, 0, "after-scan pose in the before frame: translation [m]");
  f("after_seed", &SynthConfig::after_seed, 0, 0, "after-scan random seed");
}
template <class F> void visit(DepositionConfig*, F&& f) {
  f("reference_standoff_m", &DepositionConfig::reference_standoff_m, 0.1, 5.0, "H0 of the spot model [m]");
  f("spot_radius_m", &DepositionConfig::spot_radius_m, 0.01, 2.0, "spot radius R at H0 [m]");
  f("spot_beta", &DepositionConfig::spot_beta, 1.0, 20.0, "spot exponent beta");
  f("peak_rate_mps", &DepositionConfig::peak_rate_mps, 1e-6, 1.0, "spot centre rate q_max, sprayed [m/s]");
  f("rebound_fraction", &DepositionConfig::rebound_fraction, 0.0, 0.9, "share that rebounds");
  f("nominal_flow_m3ph", &DepositionConfig::nominal_flow_m3ph, 0.1, 100.0, "nominal concrete flow [m^3/h]");
}
template <class F> void visit(FlowConfig*, F&& f) {
  f("ramp_s", &FlowConfig::ramp_s, 0.0, 60.0, "linear start/stop ramp of the concrete flow, centred on the commanded switch [s]");
  f("min_on_s", &FlowConfig::min_on_s, 0.0, 600.0, "shortest flow-on spell; shorter ones are extended [s]");
  f("min_off_s", &FlowConfig::min_off_s, 0.0, 600.0, "shortest flow-off spell; shorter gaps are bridged (flow stays on) [s]");
}
template <class F> void visit(PlannerConfig*, F&& f) {
  f("mode", &PlannerConfig::mode, 0, 0, "graded | optimal");
  f("pass_direction", &PlannerConfig::pass_direction, 0, 0, "axial | circumferential");
  f("standoff_m", &PlannerConfig::standoff_m, 0.8, 1.2, "nozzle standoff [m]");
  f("offset_along_normal", &PlannerConfig::offset_along_normal, 0, 0, "offset along -normal instead of -r");
  f("min_speed_mps", &PlannerConfig::min_speed_mps, 0.001, 10.0, "slowest nozzle speed [m/s]; optimal mode: a leaning nozzle's spot at this speed (the nozzle slower by as much as it lags a square one)");
  f("max_speed_mps", &PlannerConfig::max_speed_mps, 0.001, 10.0, "fastest nozzle speed [m/s]");
  f("max_rounds", &PlannerConfig::max_rounds, 1, 1000, "round limit");
  f("time_budget_s", &PlannerConfig::time_budget_s, 0.0, 604800.0, "wall clock of one plan; no round starts once spent (0: one round) [s]");
  f("sample_step_m", &PlannerConfig::sample_step_m, 0.001, 0.1, "integration step along a pass [m]");
  f("segment_length_m", &PlannerConfig::segment_length_m, 0.02, 2.0, "optimal mode: constant-speed piece of a pass [m]");
  f("time_weight_mm2_per_s", &PlannerConfig::time_weight_mm2_per_s, 0.0, 1e6, "optimal mode: residual mm^2 traded per s of spraying");
  f("finish_tolerance_m", &PlannerConfig::finish_tolerance_m, 0.001, 0.05, "optimal mode: flush tolerance [m]");
  f("edge_overrun_m", &PlannerConfig::edge_overrun_m, 0.0, 0.5, "pass run-on past the bay ends [m]");
  f("leaned_edge_overrun_m", &PlannerConfig::leaned_edge_overrun_m, 0.0, 0.5, "at most this run-on where the nozzle leans at a bay end (a face past it), the lean held; the nozzle's lean keeps room for it [m]; 0 = none");
  f("levelling_spacing_ratio", &PlannerConfig::levelling_spacing_ratio, 0.2, 1.0, "optimal mode: pass spacing / two-pass spacing");
  f("levelling_late_spacing_ratio", &PlannerConfig::levelling_late_spacing_ratio, 0.2, 1.0, "optimal mode: levelling_spacing_ratio of the rounds after the first once the layer left is thin (fewer, longer pump spells)");
  f("levelling_pitch_window", &PlannerConfig::levelling_pitch_window, 0.0, 0.2, "optimal mode: the pass lines' pitch is the one of least ripple across equal lines (deposition.least_ripple_pitch) within +- this share of the spacing ratio x the two-pass spacing (0: exactly that; at most 0.2: the ripple falls with the pitch overall, a wider window slides to its low end)");
  f("levelling_late_edge_overrun_m", &PlannerConfig::levelling_late_edge_overrun_m, 0.0, 0.5, "optimal mode: edge_overrun_m of those rounds [m]");
  f("levelling_late_td_quantile", &PlannerConfig::levelling_late_td_quantile, 0.5, 1.0, "optimal mode: share of the open cells whose TD must be within what a wide round lays at the slowest speed (1.25x where the look-ahead counted on them: levelling_lookahead_late_lines, levelling_lookahead_rounds > 1, wide lines unlike the close ones) before the wide lines are taken");
  f("levelling_guard_band_m", &PlannerConfig::levelling_guard_band_m, 0.0, 0.1, "optimal mode: residual band (+-) past which a cell's error costs levelling_guard_weight more [m]");
  f("levelling_guard_weight", &PlannerConfig::levelling_guard_weight, 0.0, 1e6, "optimal mode: squared error past the guard band per squared error off target (0: least squares only)");
  f("levelling_lookahead_rounds", &PlannerConfig::levelling_lookahead_rounds, 1, 10, "optimal mode: a round's dwells are solved as if this many rounds could spray them, then clipped to one round's (1: no look-ahead); with levelling_lookahead_late_lines the round's own lines take one round's dwell and the wide lines the rest");
  f("levelling_lookahead_late_lines", &PlannerConfig::levelling_lookahead_late_lines, 0, 0, "optimal mode: a round on the close lines solves the look-ahead's later rounds on the wide late lines (levelling_late_spacing_ratio, the run-on), as they will be sprayed, not on its own lines: it leaves them a layer they can lay; the wide lines are then taken up to 1.25x their layer (levelling_late_td_quantile); not in the last round max_rounds allows; needs levelling_lookahead_rounds > 1 (false: the later rounds on the round's own lines)");
  f("levelling_executed_corrections", &PlannerConfig::levelling_executed_corrections, 0, 10, "optimal mode: re-solves of a round's dwells with what its timed passes lay beyond the solve (turns sprayed through, pump spells, speed ramps) as a fixed deposit (0: none)");
  f("graded_executed_corrections", &PlannerConfig::graded_executed_corrections, 0, 10, "graded mode: re-solves of a region's pass speeds with what its timed passes lay beyond the solve (leads, turns sprayed through, pump spells, speed ramps) as a fixed deposit, the round's regions planned before it counted too (0: none, each region alone as the thesis)");
  f("graded_thesis_objective", &PlannerConfig::graded_thesis_objective, 0, 0, "graded mode: the thesis's speed objective as written (one target per region, no over-fill guard)");
  f("graded_last_edge_overrun_m", &PlannerConfig::graded_last_edge_overrun_m, 0.0, 1.0, "graded mode: edge_overrun_m of the level-1 rounds, whose passes lay the last layer on the bay's end columns (0: edge_overrun_m) [m]");
  f("graded_split_gap_m", &PlannerConfig::graded_split_gap_m, 0.0, 100.0, "graded mode: a region's pass line is cut into several passes where more than this length of wall along it holds none of the region's cells, instead of spraying the cells between at the pass's speed (0: never) [m]");
  f("graded_end_zone_m", &PlannerConfig::graded_end_zone_m, 0.0, 0.6, "graded mode: a level-1 pass that runs on past a bay end has a speed of its own over this much of the bay's end and the run-on, so the end columns, short by what every earlier round left them, can be filled (0: one speed per pass, the thesis) [m]");
  f("graded_level_margin_m", &PlannerConfig::graded_level_margin_m, 0.0, 0.02, "graded mode: a cell whose planned TD is within this of level 1's floor (+50 mm) still counts as level 1 for the rounds: the executed deposit differs from the planner's by up to about 0.6 mm on a cell, and a cell left at +40..+50 mm gets a last pass where one helps (a pass that reaches only such level-0 cells is left out when it would take them further from their targets) [m]");
  f("graded_overfill_allowance_m", &PlannerConfig::graded_overfill_allowance_m, 0.0, 0.05, "graded mode: fill past flush a cell may take before it counts as over-filled [m]");
  f("graded_guard_weight", &PlannerConfig::graded_guard_weight, 0.0, 1e4, "graded mode: cost of over-fill past the allowance per unit off target (0: no guard)");
}
template <class F> void visit(OrderingConfig*, F&& f) {
  f("method", &OrderingConfig::method, 0, 0, "aco | ga | nn | exact | best");
  f("seed", &OrderingConfig::seed, 0, 0, "random seed");
  f("aco_ants_per_region", &OrderingConfig::aco_ants_per_region, 0.1, 100.0, "ants = ratio * regions");
  f("aco_alpha", &OrderingConfig::aco_alpha, 0.0, 10.0, "pheromone weight");
  f("aco_beta", &OrderingConfig::aco_beta, 0.0, 20.0, "heuristic weight");
  f("aco_rho", &OrderingConfig::aco_rho, 0.0, 1.0, "evaporation");
  f("aco_q", &OrderingConfig::aco_q, 1e-6, 1e6, "pheromone deposit Q");
  f("aco_iterations", &OrderingConfig::aco_iterations, 1, 100000, "ant colony iterations");
  f("ga_population", &OrderingConfig::ga_population, 2, 100000, "GA population");
  f("ga_crossover", &OrderingConfig::ga_crossover, 0.0, 1.0, "crossover probability");
  f("ga_mutation", &OrderingConfig::ga_mutation, 0.0, 1.0, "mutation probability");
  f("ga_generations", &OrderingConfig::ga_generations, 1, 100000, "GA generations");
  f("exact_max_regions", &OrderingConfig::exact_max_regions, 1, 20, "largest n solved exactly");
  f("local_search", &OrderingConfig::local_search, 0, 0, "polish with 2-opt/or-opt/flips");
  f("time_budget_s", &OrderingConfig::time_budget_s, 0.01, 86400.0, "wall clock of one solve; colony, GA and kicks stop once spent [s]");
  f("ils_kicks_per_region", &OrderingConfig::ils_kicks_per_region, 0, 100000, "large instances (>= 150 regions): kicks per region");
}
template <class F> void visit(RobotConfig*, F&& f) {
  f("urdf_path", &RobotConfig::urdf_path, 0, 0, "URDF file; empty = bundled manipulator");
  f("base_position_m", &RobotConfig::base_position_m, 0, 0, "robot base in the tunnel frame [m]");
  f("place_base", &RobotConfig::place_base, 0, 0, "with clearance.enabled: move the base along the axis to the nearest place where the arm has room to slew every way (a face in the scan; the rig's carrier moves with it)");
  f("max_base_shift_m", &RobotConfig::max_base_shift_m, 0.0, 20.0, "farthest place_base moves the base from base_position_m [m]");
  f("ik_position_tolerance_m", &RobotConfig::ik_position_tolerance_m, 1e-6, 0.1, "IK position tolerance [m]");
  f("ik_angle_tolerance_rad", &RobotConfig::ik_angle_tolerance_rad, 1e-5, 0.5, "IK axis tolerance [rad]");
  f("ik_max_restarts", &RobotConfig::ik_max_restarts, 0, 10000, "random restarts per failed solve");
  f("ik_max_iterations", &RobotConfig::ik_max_iterations, 1, 100000, "IK iterations per attempt");
  f("ik_max_joint_step", &RobotConfig::ik_max_joint_step, 0.001, 10.0, "max joint change between waypoints [rad or m]");
}
template <class F> void visit(TimingConfig*, F&& f) {
  f("trajectory_rate_hz", &TimingConfig::trajectory_rate_hz, 1.0, 1000.0, "trajectory sampling [Hz]");
  f("start_fraction_k1", &TimingConfig::start_fraction_k1, 0.01, 1.0, "accelerating share of the start");
  f("end_fraction_k2", &TimingConfig::end_fraction_k2, 0.0, 0.99, "cruising share of the end");
  f("start_length_m", &TimingConfig::start_length_m, 0.0, 5.0, "start segment length [m]");
  f("end_length_m", &TimingConfig::end_length_m, 0.0, 5.0, "end segment length [m]");
  f("min_lead_s", &TimingConfig::min_lead_s, 0.0, 10.0, "least duration of a lead-in or lead-out; default half of flow.ramp_s, whose ramp runs on it [s]");
  f("pso_particles", &TimingConfig::pso_particles, 2, 1000, "swarm size");
  f("pso_iterations", &TimingConfig::pso_iterations, 1, 10000, "swarm iterations");
  f("pso_time_budget_s", &TimingConfig::pso_time_budget_s, 0.0, 604800.0, "wall clock of the swarm tuning; swarms stop iterating once spent [s]");
  f("pso_seed", &TimingConfig::pso_seed, 0, 0, "swarm random seed");
  f("pso_a", &TimingConfig::pso_a, 0.0, 10.0, "acceleration coefficient slope a");
  f("pso_b", &TimingConfig::pso_b, 0.0, 10.0, "acceleration coefficient offset b");
  f("pso_w_min", &TimingConfig::pso_w_min, 0.0, 2.0, "smallest inertia weight");
  f("pso_w_max", &TimingConfig::pso_w_max, 0.0, 2.0, "largest inertia weight");
  f("max_lead_length_m", &TimingConfig::max_lead_length_m, 0.01, 5.0, "swarm bound of start/end lengths [m]");
  f("turn_speed_mps", &TimingConfig::turn_speed_mps, 0.0, 10.0, "nozzle speed mid turn-around [m/s]; 0 = pass speeds");
  f("turn_run_m", &TimingConfig::turn_run_m, 0.0, 2.0, "straight run before/after each turn arc [m]");
  f("speed_change_accel_mps2", &TimingConfig::speed_change_accel_mps2, 0.01, 100.0, "peak acceleration of speed changes inside a pass [m/s^2]");
  f("turn_accel_mps2", &TimingConfig::turn_accel_mps2, 0.0, 100.0, "centripetal acceleration on turn arcs and speed changes on their runs [m/s^2]; 0 = speed_change_accel_mps2");
  f("min_turn_s", &TimingConfig::min_turn_s, 0.0, 60.0, "least duration of a turn-around at its own speed, so the pump can switch off over it (flow.min_off_s) [s]; 0 = none");
  f("spray_on_turns", &TimingConfig::spray_on_turns, 0, 0, "spray on the turn-arounds");
  f("nozzle_max_speed_mps", &TimingConfig::nozzle_max_speed_mps, 0.01, 10.0, "nozzle speed limit [m/s]");
  f("nozzle_max_accel_mps2", &TimingConfig::nozzle_max_accel_mps2, 0.01, 100.0, "nozzle acceleration limit [m/s^2]");
  f("joint_limit_margin", &TimingConfig::joint_limit_margin, 0.0, 0.5, "share of joint vel/acc limits kept free by the swarm and the speed caps");
  f("max_replans", &TimingConfig::max_replans, 0, 20, "re-plans at lower speeds where timed passes break a joint limit");
  f("tune_with_pso", &TimingConfig::tune_with_pso, 0, 0, "tune the timing per region by swarm (AIWCPSO); kept when faster within the same limits");
}

// g(name, member pointer to the section) for every section of Config.
template <class F> void visit(ClearanceConfig*, F&& f) {
  f("enabled", &ClearanceConfig::enabled, 0, 0, "check the space allowance along every trajectory");
  f("octree_resolution_m", &ClearanceConfig::octree_resolution_m, 0.005, 0.5, "leaf edge of the wall octree [m]");
  f("link_margin_m", &ClearanceConfig::link_margin_m, 0.0, 5.0, "least link-to-wall distance [m]");
  f("nozzle_margin_m", &ClearanceConfig::nozzle_margin_m, 0.0, 5.0, "least nozzle-to-wall distance (links nozzle*) [m]");
  f("base_margin_m", &ClearanceConfig::base_margin_m, 0.001, 5.0, "least wall distance of the links no joint moves (the base) [m]");
  f("self_margin_m", &ClearanceConfig::self_margin_m, 0.0, 5.0, "least distance between non-neighbouring links [m]");
  f("carrier_tolerance_m", &ClearanceConfig::carrier_tolerance_m, 0.0, 1.0, "scan points this far outside the rig carrier's footprint or above its top count as the machine's own [m]");
  f("reroute_transits", &ClearanceConfig::reroute_transits, 0, 0, "re-route joint moves closer than the margins through a via posture of maximum space allowance");
  f("via_allowance_m", &ClearanceConfig::via_allowance_m, 0.0, 5.0, "allowance beyond the margins sought at a via posture [m]");
  f("sampled_route_nodes", &ClearanceConfig::sampled_route_nodes, 0, 100000, "postures the sampled planner (joint-space RRT-Connect) may add per move no via route clears; 0 = off");
  f("null_space_gain", &ClearanceConfig::null_space_gain, 0.0, 100.0, "clearance term of the regions' joint tracking (null-space drift from the wall, per metre of path); 0 = off");
  f("null_space_influence_m", &ClearanceConfig::null_space_influence_m, 0.01, 10.0, "links' key points nearer the wall than this are pushed away by the clearance term [m]");
  f("max_nozzle_lean_rad", &ClearanceConfig::max_nozzle_lean_rad, 0.0, 1.0472, "the nozzle leans at most this far off square to stay clear of what is not wall (face, duct) [rad]; 0 = square only");
  f("nozzle_lean_fade_rad_per_m", &ClearanceConfig::nozzle_lean_fade_rad_per_m, 0.01, 10.0, "a needed lean fades out over the wall around its cell at this rate [rad per m of wall]; below 1 / planner.standoff_m");
}

template <class F> void visit(RescanConfig*, F&& f) {
  f("reference", &RescanConfig::reference, 0, 0, "dry | box | mask: the areas the scans are registered on");
  f("dry_threshold_m", &RescanConfig::dry_threshold_m, 0.0, 0.1, "dry: predicted deposit below this is unsprayed [m]");
  f("reference_margin_m", &RescanConfig::reference_margin_m, 0.0, 5.0, "dry: sprayed cells grown by this [m]");
  f("reference_box_min_m", &RescanConfig::reference_box_min_m, 0, 0, "box: minimum corner, before frame [m]");
  f("reference_box_max_m", &RescanConfig::reference_box_max_m, 0, 0, "box: maximum corner, before frame [m]");
  f("mask_radius_m", &RescanConfig::mask_radius_m, 0.001, 10.0, "mask: before points within this of a mask point [m]");
  f("voxel_size_m", &RescanConfig::voxel_size_m, 0.0, 1.0, "voxel edge of the reference clouds for GICP [m]; 0 = off");
  f("coarse_correspondence_m", &RescanConfig::coarse_correspondence_m, 0.001, 10.0, "GICP correspondence distance, first stage [m]");
  f("fine_correspondence_m", &RescanConfig::fine_correspondence_m, 0.001, 10.0, "GICP correspondence distance, second stage and overlap [m]");
  f("max_iterations", &RescanConfig::max_iterations, 1, 10000, "GICP iterations per stage");
  f("min_overlap", &RescanConfig::min_overlap, 0.0, 1.0, "least share of after reference points matched");
  f("min_reference_points", &RescanConfig::min_reference_points, 10, 100000000, "least reference points per scan");
  f("cylinder_radius_m", &RescanConfig::cylinder_radius_m, 0.001, 1.0, "M3C2 cylinder radius [m]");
  f("cylinder_half_length_m", &RescanConfig::cylinder_half_length_m, 0.01, 10.0, "M3C2 cylinder half length [m]");
  f("min_cylinder_points", &RescanConfig::min_cylinder_points, 1, 100000, "least points per scan in a cylinder");
  f("calibration_min_deposit_m", &RescanConfig::calibration_min_deposit_m, 0.0, 1.0, "least predicted deposit of a calibration cell [m]");
  f("correction_time_weight_mm2_per_s", &RescanConfig::correction_time_weight_mm2_per_s, 0.0, 1e6,
    "the corrective round's planner.time_weight_mm2_per_s (optimal mode)");
  f("correction_spacing_ratio", &RescanConfig::correction_spacing_ratio, 0.2, 1.0,
    "the corrective round's planner.levelling_spacing_ratio (optimal mode)");
  f("correction_edge_overrun_m", &RescanConfig::correction_edge_overrun_m, 0.0, 0.5,
    "the corrective round's planner.edge_overrun_m [m]");
}

template <class G> void visit_sections(G&& g) {
  g("io", &Config::io);
  g("preprocess", &Config::preprocess);
  g("profile", &Config::profile);
  g("normals", &Config::normals);
  g("grid", &Config::grid);
  g("regions", &Config::regions);
  g("synth", &Config::synth);
  g("deposition", &Config::deposition);
  g("flow", &Config::flow);
  g("planner", &Config::planner);
  g("ordering", &Config::ordering);
  g("robot", &Config::robot);
  g("timing", &Config::timing);
  g("clearance", &Config::clearance);
  g("rescan", &Config::rescan);
}

}  // namespace shotcrete::fields
