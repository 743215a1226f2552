#pragma once
// The one configuration of the product. Mirrored in config/default.yaml (one section per stage)
// and exposed unchanged to Python and ROS through the field table in config_fields.hpp.
// Every value carries its unit in its name or its doc string.
#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>

#include "shotcrete/types.hpp"

namespace shotcrete {

// Choices of the configuration: named enums (types.hpp), read and written by these names.

/// planner.mode: the thesis' graded rounds, or levelling rounds that optimise residual and time.
enum class PlannerMode { graded, optimal };
constexpr std::array<EnumName<PlannerMode>, 2> enum_names(PlannerMode) {
  return {{{PlannerMode::graded, "graded"}, {PlannerMode::optimal, "optimal"}}};
}

/// planner.pass_direction: passes along the tunnel, or around it.
enum class PassDirection { axial, circumferential };
constexpr std::array<EnumName<PassDirection>, 2> enum_names(PassDirection) {
  return {{{PassDirection::axial, "axial"}, {PassDirection::circumferential, "circumferential"}}};
}

/// grid.bay: which stretch of the scan along the axis is the bay to spray (docs/architecture.md §3,
/// "Bay selection"): the whole scan, a chainage range from the config, or detected as the stretch
/// that is not lining.
enum class BaySelection { whole, range, detect };
constexpr std::array<EnumName<BaySelection>, 3> enum_names(BaySelection) {
  return {{{BaySelection::whole, "whole"}, {BaySelection::range, "range"}, {BaySelection::detect, "detect"}}};
}

/// ordering.method: the region-ordering solver (ordering.hpp).
enum class OrderingMethod { aco, ga, nn, exact, best };
constexpr std::array<EnumName<OrderingMethod>, 5> enum_names(OrderingMethod) {
  return {{{OrderingMethod::aco, "aco"},
           {OrderingMethod::ga, "ga"},
           {OrderingMethod::nn, "nn"},
           {OrderingMethod::exact, "exact"},
           {OrderingMethod::best, "best"}}};
}

struct IoConfig {
  double max_extent_m = 1000.0;  // a cloud larger than this is taken for millimetres and refused
  double unit_scale = 1.0;       // multiply input coordinates by this (0.001 for a mm cloud)
};

struct PreprocessConfig {
  bool crop_enabled = false;
  Eigen::Vector3d crop_min_m{-1e3, -1e3, -1e3};  // tunnel frame, m
  Eigen::Vector3d crop_max_m{1e3, 1e3, 1e3};
  double voxel_size_m = 0.01;    // voxel edge for downsampling (5x finer than the grid); 0 = off
  int outlier_neighbors = 8;     // k of the statistical outlier filter; 0 = off
  double outlier_std_ratio = 3.0;  // points beyond mean + ratio * std of k-NN distance are removed
};

struct ProfileConfig {
  double design_radius_m = 5.6;                 // radius of the circular design profile
  std::string section_path = "";  // design cross-section (CSV of lines and arcs, docs/architecture.md §3); empty: the circle
  Eigen::Vector3d axis_origin_m{0.0, 0.0, 0.0};  // a point on the tunnel axis
  Eigen::Vector3d axis_direction{1.0, 0.0, 0.0};  // advance direction (normalised on use)
  std::string alignment_path = "";  // alignment CSV (chainage_m,x_m,y_m,z_m): the axis where the scan lies; empty: the two above
  bool estimate_axis = false;                   // fit the axis to the cloud (docs/architecture.md §3)
  bool estimate_axis_origin = true;  // with estimate_axis: fit the centre too; false keeps axis_origin_m
  double min_fit_arc_rad = 2.618;    // a fitted axis needs the wall to cover this arc around it (150 deg)
  double max_deviation_m = 1.0;  // points farther than this from the design line are ignored
};

struct NormalsConfig {
  int k_neighbors = 20;  // neighbours per PCA normal
};

struct GridConfig {
  double cell_size_m = 0.05;  // cell edge along the axis and along the wall arc
  int min_points_per_cell = 1;  // cells with fewer points are marked empty
  // Bay selection: the rest of the scan (lined bay, face, floor) stays in the cloud as obstacle
  // and reference but out of the grid.
  BaySelection bay = BaySelection::detect;
  double bay_start_m = 0.0;  // bay: range; chainage of the bay's ends along the axis, from
  double bay_end_m = 0.0;    // profile.axis_origin_m (the job's frame), m
  double lined_td_m = 0.03;  // bay: detect; a cell whose TD is within this of the design line looks lined, m
  double lined_fraction = 0.9;  // a cross-section (grid column) with this share of lined cells is lining
  // A point whose normal is farther than this from the radial direction is not wall (the face,
  // a floor, a duct's flank) and stays out of the grid, rad. Dig-pit flanks tilt < 40 deg.
  double max_normal_tilt_rad = 1.0472;
  // A wall-like point this far inside the outermost surface of its lattice cell (the same rays
  // from the axis) lies on something in front of the wall (a ventilation duct's top) and stays out
  // of the grid, but in the cloud as an obstacle, m; 0 = off. Dig-pit flanks span < 0.1 m a cell.
  double obstacle_gap_m = 0.15;
};

struct RegionConfig {
  int min_region_cells = 10;  // smaller regions merge into the nearest one
};

struct SynthConfig {
  double design_radius_m = 5.6;  // design line of the synthetic bay
  std::string section_path = "";  // design section CSV (as profile.section_path); empty: the circle
  double length_m = 1.2;         // bay length between two arches
  double theta_min_rad = 0.0;    // right springline
  double theta_max_rad = 3.141592653589793;  // left springline (pi)
  double base_overbreak_m = 0.15;  // uniform over-break outside the design line
  int pit_count = 30;            // number of dig pits
  double pit_depth_min_m = 0.02;  // Tmax range of the pits
  double pit_depth_max_m = 0.14;
  double pit_radius_min_m = 0.4;  // D range of the pits (on the unrolled wall)
  double pit_radius_max_m = 1.0;
  double pit_shape_alpha = 1.5;   // dT = Tmax (1 - d^2/D^2)^alpha
  double noise_m = 0.005;         // scanner noise (std dev, radial)
  double points_per_cell = 20.0;  // mean points per 50 mm x 50 mm cell
  std::uint64_t seed = 1;
  // Opt-in rock protrusion (0 = none): a bump of the pits' shape standing protrusion_height_m out
  // of the wall toward the axis, centred at (protrusion_d_m, protrusion_theta_rad).
  double protrusion_height_m = 0.0;
  double protrusion_d_m = 0.6;
  double protrusion_theta_rad = 1.5708;
  double protrusion_radius_m = 0.6;  // D of the bump (on the unrolled wall)
  // Scan context (docs/architecture.md §12): what a real scan also holds around the bay, unsprayed;
  // off by default, so the default bay (and the demo's numbers) stay the bay alone.
  bool context_enabled = false;
  double context_previous_bay_m = 2.0;  // lined previous bay behind the new one (d < 0), on the design line
  double context_invert_depth_m = 1.5;  // floor plane this far below the springlines (axis height); 0 = none
  bool context_face = true;             // the face: a plane across the axis at the bay's far end (d = length_m)
  // A ventilation duct along the axis under the crown (0 = none): its top context_duct_gap_m under
  // the design line at y = context_duct_y_m (across, left positive), from the lined bay's start to
  // its outlet at d = context_duct_outlet_d_m (past the bay's far end, the default: over both bays;
  // on site the outlet hangs behind the unlined ground, which is about to be sprayed).
  double context_duct_diameter_m = 0.0;
  double context_duct_gap_m = 0.3;
  double context_duct_y_m = 0.0;
  double context_duct_outlet_d_m = 1000.0;
  // The rig's carrier: a box on the invert ending context_rig_front_d_m along the axis (the arm's
  // base stands ahead of it), centred across; 0 length = none. Needs the invert.
  double context_rig_length_m = 0.0;
  double context_rig_width_m = 2.4;
  double context_rig_height_m = 1.2;
  double context_rig_front_d_m = -0.4;
  // Muck on the invert at the face (0 height = none; needs the invert): a mound context_muck_height_m
  // high at the face, falling linearly to the invert context_muck_length_m back along the axis, and
  // across as 1 - (2y/width)^2 (a parabola context_muck_width_m wide at its foot).
  double context_muck_height_m = 0.0;
  double context_muck_length_m = 2.0;
  double context_muck_width_m = 4.0;
  // The scanner's shadow: drop every point (bay and context) the scanner at context_scanner_position_m
  // (d along the axis, y across, z up from the axis; the bay's frame) cannot see past the duct, the
  // rig and the muck, as a site scan has it.
  bool context_scanner_shadow = false;
  Eigen::Vector3d context_scanner_position_m{-1.5, 0.0, 0.0};
  // After-spraying scan (synth --after JOBDIR): the job's executed deposit per cell, scaled and roughened.
  double after_flow_scale = 1.0;         // real / modelled concrete flow (the factor rescan calibrates)
  double after_rebound_fraction = 0.08;  // real rebound share; scales the layer by (1 - it) / (1 - deposition.rebound_fraction)
  double after_thickness_noise = 0.05;   // spatially correlated layer noise, std dev as a share of the layer
  double after_noise_length_m = 0.5;     // correlation length of that noise (Gaussian covariance)
  double after_noise_m = 0.005;          // scanner noise of the after-scan (std dev along the surface normal)
  double after_points_per_cell = 20.0;   // its mean points per 50 mm x 50 mm cell (context: per same area)
  Eigen::Vector3d after_pose_rpy_rad{0.0, 0.0, 0.0};    // true pose of the after-scan in the before frame:
  Eigen::Vector3d after_pose_translation_m{0.0, 0.0, 0.0};  // p_before = R(roll, pitch, yaw) p_after + t
  std::uint64_t after_seed = 2;
};

struct DepositionConfig {
  double reference_standoff_m = 1.0;  // H0: standoff of the spot model
  // Defaults: fit of data/deposition_stroke.csv (`shotcrete deposition fit`, stroke MSE 0.46 mm^2);
  // test Fit.ConfigDefaultsMatchFreshFit keeps them in step with the data.
  double spot_radius_m = 0.1924;      // R at H0 (cone half-angle = atan(R / H0) = 10.9 deg)
  double spot_beta = 2.015;           // spot exponent; stroke exponent = beta - 1/2
  double peak_rate_mps = 0.025;       // q_max at H0, m/s of thickness, sprayed (before rebound); must be > 0
  double rebound_fraction = 0.08;     // share of sprayed concrete that does not stay on the wall
  double nominal_flow_m3ph = 5.0;     // machine's nominal concrete flow
};

// The concrete flow the pump delivers (docs/architecture.md §8): the executed deposit follows it.
// Defaults are assumptions for a small twin-piston wet-mix pump at 5 m^3/h (config/default.yaml
// says why); set them from the machine. ramp_s must not exceed min_on_s or min_off_s.
struct FlowConfig {
  double ramp_s = 2.0;     // linear start/stop ramp of the flow, centred on the commanded switch
  double min_on_s = 2.0;   // shortest spell with the flow on (shorter ones are extended)
  double min_off_s = 2.0;  // shortest spell with the flow off (shorter gaps are bridged)
};

struct PlannerConfig {
  PlannerMode mode = PlannerMode::optimal;  // optimal (levelling rounds: residual + time) or graded (thesis)
  PassDirection pass_direction = PassDirection::axial;  // axial: along the tunnel; circumferential: around
  double standoff_m = 1.0;         // nozzle to wall along the offset direction
  bool offset_along_normal = false;  // offset along -normal instead of along -r
  double min_speed_mps = 0.05;
  double max_speed_mps = 1.0;
  int max_rounds = 12;
  double time_budget_s = 1800.0;   // wall clock of one plan_bay; no round starts once it is spent
  double sample_step_m = 0.01;     // integration step of the nozzle along a pass
  double segment_length_m = 0.15;  // optimal mode: length of a constant-speed piece of a pass
  double time_weight_mm2_per_s = 500.0;  // optimal mode: squared residual (mm^2, summed over cells) worth 1 s
  double finish_tolerance_m = 0.02;    // optimal mode: stop when every cell is within this of flush
  double edge_overrun_m = 0.1;     // passes run on this far past the bay's ends (the arches)
  double leaned_edge_overrun_m = 0.1;  // at most this far where the nozzle leans at that end (a face past
                                       // it), the lean held; clearance room kept for it [m]; 0 = none
  double levelling_spacing_ratio = 0.5;  // optimal mode: pass spacing as a share of the two-pass spacing
  double levelling_late_spacing_ratio = 1.0;  // optimal mode: levelling_spacing_ratio once the layer left is thin
  double levelling_pitch_window = 0.15;  // optimal mode: the lines' pitch is the one of least ripple within +- this share of ratio x two-pass spacing (0: exactly that)
  double levelling_late_edge_overrun_m = 0.1;  // optimal mode: edge_overrun_m once the layer left is thin [m]
  double levelling_late_td_quantile = 0.95;  // optimal mode: share of the open cells whose TD must be within a wide round's layer
  double levelling_guard_band_m = 0.02;  // optimal mode: residual band (+-) past which the guard counts
  double levelling_guard_weight = 100.0;  // optimal mode: cost of a mm past the band per mm off target, squared (0: no guard)
  int levelling_lookahead_rounds = 2;  // optimal mode: rounds a round's dwells are solved for (it sprays one)
  bool levelling_lookahead_late_lines = true;  // optimal mode: a round on the close lines solves the look-ahead's later rounds on the wide late lines
  int levelling_executed_corrections = 2;  // optimal mode: re-solves of a round against its own executed deposit (0: none)
  int graded_executed_corrections = 1;  // graded mode: re-solves of a region's speeds against its own executed deposit (0: none, nor the round's other regions)
  bool graded_thesis_objective = false;  // graded mode: the thesis's objective as written (one target per region)
  double graded_last_edge_overrun_m = 0.15;  // graded mode: edge_overrun_m of the level-1 rounds (0: edge_overrun_m) [m]
  double graded_split_gap_m = 0.3;  // graded mode: a region's pass line is cut where more than this of wall holds none of its cells (0: never) [m]
  double graded_end_zone_m = 0.2;  // graded mode: level-1 passes run on past a bay end have their own speed over this much of the bay's end and the run-on (0: one speed per pass) [m]
  double graded_level_margin_m = 0.01;  // graded mode: a cell within this of level 1's floor (+50 mm) still counts as level 1 for the rounds (a pass only over such cells is kept where it helps) [m]
  double graded_overfill_allowance_m = 0.025;  // graded mode: fill past flush a reached cell may take
  double graded_guard_weight = 1000.0;  // graded mode: cost of over-fill past the allowance per unit off target
};

struct OrderingConfig {
  OrderingMethod method = OrderingMethod::best;
  std::uint64_t seed = 1;
  double aco_ants_per_region = 1.5;
  double aco_alpha = 1.0;
  double aco_beta = 5.0;
  double aco_rho = 0.3;
  double aco_q = 10.0;
  int aco_iterations = 200;
  int ga_population = 100;
  double ga_crossover = 0.9;
  double ga_mutation = 0.1;
  int ga_generations = 400;
  int exact_max_regions = 16;
  bool local_search = true;
  double time_budget_s = 8.0;     // wall clock of one solve; iterations stop once it is spent
  int ils_kicks_per_region = 20;  // large instances: iterated local search kicks per region
};

struct RobotConfig {
  std::string urdf_path = "";  // empty: the bundled shotcrete manipulator
  Eigen::Vector3d base_position_m{0.6, 0.0, -1.2};  // base link in the tunnel frame
  bool place_base = true;           // move the base along the axis to where the arm can slew every way
                                    // with via_allowance_m of room (place_base; a face in the scan)
  double max_base_shift_m = 1.5;    // farthest such a move [m]
  double ik_position_tolerance_m = 0.001;
  double ik_angle_tolerance_rad = 0.0087;  // 0.5 degree
  int ik_max_restarts = 20;
  int ik_max_iterations = 100;      // damped least-squares iterations per attempt
  double ik_max_joint_step = 0.1;   // largest joint change between path waypoints [rad or m]
};

struct TimingConfig {
  double trajectory_rate_hz = 50.0;  // sampling of the timed joint trajectory
  double start_fraction_k1 = 0.5;    // share of the start segment spent accelerating
  double end_fraction_k2 = 0.5;      // share of the end segment spent cruising
  double start_length_m = 0.1;       // nozzle path length of the start segment
  double end_length_m = 0.1;         // nozzle path length of the end segment
  double min_lead_s = 1.0;           // least duration of a lead-in or lead-out [s]: half the pump's
                                     // ramp (flow.ramp_s), which runs on it (the ramps stay off the
                                     // joint moves around a region)
  int pso_particles = 15;
  int pso_iterations = 30;
  double pso_time_budget_s = 600.0;  // wall clock of the whole swarm tuning; swarms stop iterating once spent
  std::uint64_t pso_seed = 1;
  double pso_a = 2.05;               // c1 = a Bs + b, c2 = a (1 - Bs) + b
  double pso_b = 0.5;
  double pso_w_min = 0.0;            // w = (w_max - w_min) Bs + w_min
  double pso_w_max = 1.0;
  double max_lead_length_m = 0.5;    // swarm bound of the start/end lengths
  double turn_speed_mps = 0.5;       // nozzle speed mid turn-around; 0 = keep the pass speeds
  double turn_run_m = 0.1;           // straight run before / after each turn-around arc (speed change room)
  double speed_change_accel_mps2 = 0.5;  // peak nozzle acceleration of speed changes inside a pass
  double turn_accel_mps2 = 1.0;  // centripetal acceleration on turn arcs and speed changes on turn runs; 0 = speed_change_accel_mps2
  // Least duration of a turn-around that runs at its own speed (turn_speed_mps, or the arc's
  // centripetal cap), s: the pump (flow.min_off_s, 2 s) switches off over a turn only if it lasts
  // that long; a shorter turn is sprayed through, concrete the dwell solve does not plan for.
  double min_turn_s = 2.1;
  bool spray_on_turns = false;       // spray on the turn-arounds (the planner's deposit assumes not)
  double nozzle_max_speed_mps = 1.0; // nozzle speed limit (also the swarm bound of the turn speed)
  double nozzle_max_accel_mps2 = 2.0;  // nozzle acceleration limit, tangential + centripetal
  double joint_limit_margin = 0.05;  // share of the joint velocity/acceleration limits the swarm keeps free
  int max_replans = 3;  // re-plans at lower speeds where timed passes break a joint limit
  bool tune_with_pso = false;  // plan_for_arm: tune the timing per region by swarm, keep it if faster
};

// Space allowance of the arm along its trajectory (collision/clearance): the links' URDF
// collision shapes against an octree of the wall (scan and sprayed surface) and against each other.
struct ClearanceConfig {
  bool enabled = true;                // check every timed trajectory (report.json clearance)
  double octree_resolution_m = 0.05;  // leaf edge of the wall's octree (distances read up to
                                      // half a leaf diagonal short: conservative)
  double link_margin_m = 0.3;         // least distance of a link to the wall
  double nozzle_margin_m = 0.4;       // least distance of the nozzle links (nozzle*) to the wall;
                                      // the tip faces it at the standoff less the layers to come
  double base_margin_m = 0.05;        // least distance to the wall of the links no joint moves (the base,
                                      // fixed_shapes): no room for motion, only for the rig's placing
  double self_margin_m = 0.05;        // least distance between two links that are not neighbours
  double carrier_tolerance_m = 0.1;   // scan points this far outside the carrier's footprint or
                                      // above its top still count as the machine's own (machine_points)
  bool reroute_transits = true;       // joint moves closer than the margins go through a via posture
                                      // of maximum space allowance (clear_transits)
  double via_allowance_m = 0.3;       // allowance beyond the margins sought at a via posture; past
                                      // it the posture nearest the straight move wins
  int sampled_route_nodes = 2500;     // postures the sampled planner (joint-space RRT-Connect) may add
                                      // per move no via route clears; 0 = off
  double null_space_gain = 1.0;       // clearance term of the regions' joint tracking (the 3 spare
                                      // DOF keep the links from the wall while spraying); 0 = off
  double null_space_influence_m = 1.5;  // links' key points nearer the wall than this are pushed away [m]
                                        // (while spraying they work 1-1.5 m from it at a 1 m standoff)
  double max_nozzle_lean_rad = 0.6109;  // the nozzle may lean this far off square to keep clear of what is
                                        // not wall (a face, a duct): 35 deg, the steepest spraying angle
                                        // of nozzlemen's practice at corners; 0 = square only
  double nozzle_lean_fade_rad_per_m = 0.5;  // a needed lean fades out over the wall around its cell at this
                                            // rate [rad per m of wall]: along a pass the nozzle moves at
                                            // 1 - rate * standoff of its spot's speed or more (< 1 / standoff)
};

/// rescan.reference: where the two scans are registered (docs/architecture.md §12).
enum class ReferenceArea { dry, box, mask };
constexpr std::array<EnumName<ReferenceArea>, 3> enum_names(ReferenceArea) {
  return {{{ReferenceArea::dry, "dry"}, {ReferenceArea::box, "box"}, {ReferenceArea::mask, "mask"}}};
}

// Re-scan after spraying (docs/architecture.md §12): registration on unsprayed reference areas,
// M3C2-style thickness along the wall normal, flow calibration.
struct RescanConfig {
  ReferenceArea reference = ReferenceArea::dry;  // dry: outside the cells the job sprayed; box; mask cloud
  double dry_threshold_m = 0.002;    // dry: a cell whose predicted deposit is below this is unsprayed
  double reference_margin_m = 0.3;   // dry: sprayed cells grown by this (overspray, rebound) [m]
  Eigen::Vector3d reference_box_min_m{-1e3, -1e3, -1e3};  // box: reference corners in the before frame [m]
  Eigen::Vector3d reference_box_max_m{1e3, 1e3, 1e3};
  double mask_radius_m = 0.1;        // mask: before points within this of a mask point are reference [m]
  double voxel_size_m = 0.06;        // downsampling of both reference clouds for GICP [m]
  double coarse_correspondence_m = 0.3;  // GICP max correspondence distance, first stage [m]
  double fine_correspondence_m = 0.05;   // second stage, and the overlap test [m]
  int max_iterations = 60;           // GICP iterations per stage
  double min_overlap = 0.5;          // share of after reference points with a before point within fine_correspondence_m
  int min_reference_points = 500;    // fewer reference points (after voxelling) is refused
  double cylinder_radius_m = 0.025;  // M3C2 projection cylinder radius [m]
  double cylinder_half_length_m = 0.5;  // its half length along the normal, centred on the scanned wall [m]
  int min_cylinder_points = 3;       // fewer points of either scan in a cylinder: no measurement
  double calibration_min_deposit_m = 0.02;  // cells predicted to get at least this enter the calibration [m]
  // The corrective round's planner.time_weight_mm2_per_s: a thin finishing layer, where the last
  // cells off flush matter more than its seconds (rescan bench: 500 left cells at +-28..33 mm, 100
  // at -21..+27 mm for 5 % more spraying).
  double correction_time_weight_mm2_per_s = 100.0;
  // The corrective round's planner.levelling_spacing_ratio: its layer is thin (20-60 mm), and with
  // the job's close lines (0.5) a pump spell of 2 s on four overlapping lines lays more than the
  // thin cells need (rescan bench, 3 cases: 0.5 left -21..+25-29 mm, RMS 5.6 mm; 1.0 -19..+22-24
  // mm, RMS 4.6-4.9 mm, 16-23 % less cycle time).
  double correction_spacing_ratio = 1.0;
  // The corrective round's planner.edge_overrun_m: its end cells are off flush by a few
  // centimetres, too little for a spell of their own, so the lines run on further past the bay's
  // ends to give each end cell the spot's whole width (rescan bench, with the spacing above: 0.1
  // left -19..+24 mm, RMS 4.6-4.9 mm; 0.2 -22..+20 mm, RMS 4.1-4.2 mm, 8-9 % more cycle time).
  double correction_edge_overrun_m = 0.2;
};

struct Config {
  IoConfig io;
  PreprocessConfig preprocess;
  ProfileConfig profile;
  NormalsConfig normals;
  GridConfig grid;
  RegionConfig regions;
  SynthConfig synth;
  DepositionConfig deposition;
  FlowConfig flow;
  PlannerConfig planner;
  OrderingConfig ordering;
  RobotConfig robot;
  TimingConfig timing;
  ClearanceConfig clearance;
  RescanConfig rescan;
};

/// Defaults overridden by a YAML file; unknown sections/keys, wrong types and out-of-range values
/// throw std::invalid_argument naming the key.
Config load_config(const std::string& path);
Config config_from_yaml(const std::string& text);
std::string config_to_yaml(const Config& config);
/// Throws std::invalid_argument naming the first offending key, its value and the allowed range.
void validate(const Config& config);

}  // namespace shotcrete
