// Design profiles: sections of lines and arcs, TD along the profile's normal, the grid's volume on
// them, against closed forms and a brute-force distance to the polyline.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <string>

#include "shotcrete/config.hpp"
#include "shotcrete/io/synth.hpp"
#include "shotcrete/surface/grid.hpp"
#include "shotcrete/surface/preprocess.hpp"
#include "shotcrete/surface/profile.hpp"
#include "shotcrete/surface/surface.hpp"

using namespace shotcrete;

namespace {

constexpr double kPi = 3.14159265358979323846;

std::string data(const std::string& name) { return std::string(SHOTCRETE_DATA_DIR) + "/" + name; }

// Distance of p to the flattened polyline, by brute force over every chord (the reference).
double polyline_distance(const DesignProfile& prof, const Eigen::Vector2d& p) {
  double best = 1e300;
  for (std::size_t i = 0; i + 1 < prof.polyline_m.size(); ++i) {
    const Eigen::Vector2d a = prof.polyline_m[i], e = prof.polyline_m[i + 1] - a;
    const double s = std::clamp((p - a).dot(e) / e.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (a + s * e - p).norm());
  }
  return best;
}

std::string write_temp(const std::string& name, const std::string& text) {
  // Prefixed: other test binaries write their own bad.csv into TempDir at the same time (ctest -j).
  const std::string path = testing::TempDir() + "profile_" + name;
  std::ofstream(path) << text;
  return path;
}

}  // namespace

TEST(Profile, SemicircleSectionIsTheCircle) {
  // One arc of 180 deg (bulge 1) from the right springline to the left: the circle of radius 5.6.
  const DesignProfile p = DesignProfile::from_section({{5.6, 0.0, 1.0}, {-5.6, 0.0, 0.0}});
  EXPECT_FALSE(p.is_circle());
  EXPECT_NEAR(p.theta_min_rad(), 0.0, 1e-12);
  EXPECT_NEAR(p.theta_max_rad(), kPi, 1e-12);
  EXPECT_NEAR(p.radius_m, 5.6, 2e-4);  // chord length / span: within the flattening's 0.2 mm
  for (double th = 0.0; th <= kPi; th += 0.01) {
    EXPECT_NEAR(p.radius_at(th), 5.6, 2e-4) << th;
    EXPECT_NEAR(p.normal_cos_at(th), 1.0, 1e-4) << th;
    EXPECT_NEAR(p.td_m(5.75, th), 0.15, 3e-4) << th;
  }
  EXPECT_FALSE(p.covers(-0.1));
  EXPECT_TRUE(std::isnan(p.td_m(5.6, -0.1)));  // off the span: not wall
  EXPECT_TRUE(std::isnan(p.td_m(5.6, 3.3)));
  // Geometry runs on along the end chords (the grid's end rows reach past the span).
  EXPECT_NEAR(p.radius_at(-0.01), 5.6, 2e-3);
  EXPECT_TRUE(p.normal_at(-0.01).allFinite());
  // The same arc given clockwise (left to right, bulge -1) is the same line.
  const DesignProfile q = DesignProfile::from_section({{-5.6, 0.0, -1.0}, {5.6, 0.0, 0.0}});
  for (double th = 0.05; th < kPi; th += 0.1) EXPECT_NEAR(q.radius_at(th), p.radius_at(th), 1e-9);
}

TEST(Profile, TdOnAStraightWallIsTheDistanceToItsLine) {
  // A vertical wall y = 5 from z = -2 to z = 3: R(theta) = 5 / cos(theta), and TD of any point is
  // y - 5 exactly, whatever its angle.
  const DesignProfile p = DesignProfile::from_section({{5.0, -2.0}, {5.0, 3.0}});
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> uy(4.0, 6.0), uz(-1.5, 2.0);  // rays within the wall's span
  for (int i = 0; i < 200; ++i) {
    const double y = uy(rng), z = uz(rng), th = std::atan2(z, y);
    EXPECT_NEAR(p.radius_at(th), 5.0 / std::cos(th), 1e-12);
    EXPECT_NEAR(p.td_m(std::hypot(y, z), th), y - 5.0, 1e-12);
    EXPECT_NEAR(p.radial_offset_m(p.td_m(std::hypot(y, z), th), th), std::hypot(y, z) - 5.0 / std::cos(th), 1e-12);
  }
  const Eigen::Vector2d n = p.normal_at(0.3);
  EXPECT_NEAR(n.x(), 1.0, 1e-12);
  EXPECT_NEAR(n.y(), 0.0, 1e-12);
}

TEST(Profile, HorseshoeTdMatchesTheBruteForceDistanceToTheLine) {
  const DesignProfile p = DesignProfile::from_section(read_section_csv(data("profiles/horseshoe.csv")));
  EXPECT_NEAR(p.theta_min_rad(), std::atan2(-2.0, 5.419982), 1e-6);
  EXPECT_NEAR(p.radius_at(kPi / 2), 5.6, 2e-4);  // the crown arc
  // The side wall at the springline is still the crown's tangent: TD along it is radial.
  EXPECT_NEAR(p.normal_cos_at(0.0), 1.0, 1e-3);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> uth(p.theta_min_rad() + 0.02, p.theta_max_rad() - 0.02), ut(-0.3, 0.5);
  double worst = 0.0;
  for (int i = 0; i < 2000; ++i) {
    const double th = uth(rng), t = ut(rng);
    // A point t along the line's normal from the line's point at th.
    const Eigen::Vector2d on = p.radius_at(th) * Eigen::Vector2d(std::cos(th), std::sin(th));
    const Eigen::Vector2d q = on + t * p.normal_at(th);
    const double r = q.norm(), thq = std::atan2(q.y(), q.x());
    const double brute = (t >= 0 ? 1.0 : -1.0) * polyline_distance(p, q);
    worst = std::max(worst, std::abs(p.td_m(r, thq) - brute));
  }
  // Second order in TD over the arcs' radii (>= 5.6 m): t^2 / (2 rho) < 23 mm at 0.5 m in the
  // worst case; 1 mm covers what the flattening and the chords' kinks leave.
  EXPECT_LT(worst, 1e-3);
}

TEST(Profile, BadSectionsAreRefusedNamingTheProblem) {
  auto refuses = [](const std::vector<SectionVertex>& v, const std::string& fragment) {
    try {
      DesignProfile::from_section(v);
      ADD_FAILURE() << "accepted a section that should be refused (" << fragment << ")";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
    }
  };
  refuses({{5.0, 0.0}}, "at least 2 vertices");
  refuses({{5.0, 0.0}, {5.0, 0.0}}, "coincide");
  refuses({{5.0, 0.0}, {NAN, 1.0}}, "not finite");
  // A zig-zag whose middle edge turns back: a ray meets it three times.
  refuses({{5.0, 0.0}, {0.0, 5.0}, {4.0, 4.5}, {-5.0, 0.0}}, "star-shaped");
  // Round the invert: crosses the cut straight below the axis.
  refuses({{-3.0, -4.0}, {3.0, -4.0}}, "star-shaped");
  refuses({{5.0, 0.0}, {10.0, 0.0}}, "star-shaped");  // an edge along a ray
  refuses({{0.0, 0.0}, {5.0, 1.0}}, "through the axis");
}

TEST(Profile, SectionCsvErrorsNameTheFileAndLine) {
  const std::string good = write_temp("good.csv", "# a comment\ny_m,z_m,bulge\n5.6,0,1\n\n-5.6,0\n");
  const auto v = read_section_csv(good);
  ASSERT_EQ(v.size(), 2u);
  EXPECT_DOUBLE_EQ(v[0].bulge, 1.0);
  EXPECT_DOUBLE_EQ(v[1].bulge, 0.0);
  const std::string bad = write_temp("bad.csv", "5.6,0,1\n-5.6,zero\n");
  try {
    read_section_csv(bad);
    ADD_FAILURE() << "accepted a malformed CSV";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("bad.csv, line 2"), std::string::npos) << e.what();
  }
  EXPECT_THROW(read_section_csv(write_temp("empty.csv", "# nothing\n")), std::invalid_argument);
  EXPECT_THROW(read_section_csv(write_temp("cols.csv", "1,2,3,4\n")), std::invalid_argument);
  EXPECT_THROW(read_section_csv(testing::TempDir() + "missing.csv"), std::invalid_argument);
  Config c;
  c.profile.section_path = good;
  c.profile.estimate_axis = true;
  EXPECT_THROW(validate(c), std::invalid_argument);  // a circle fit cannot give a section's axis
}

TEST(Profile, GridVolumeOnAHorseshoeIsTheOffsetArea) {
  // A horseshoe wall a uniform 0.1 m outside its design line (no pits, no noise): the missing volume
  // is the area between the line and its offset, L t + (turning angle) t^2 / 2 for a line of arcs
  // joined tangentially, times the bay's length.
  Config cfg;
  cfg.synth.section_path = data("profiles/horseshoe.csv");
  cfg.synth.pit_count = 0;
  cfg.synth.noise_m = 0.0;
  cfg.synth.base_overbreak_m = 0.1;
  cfg.synth.theta_min_rad = -1.0;  // beyond the section's span on both sides: the whole section
  cfg.synth.theta_max_rad = 4.2;
  cfg.synth.points_per_cell = 30;
  const SyntheticBay bay = make_synthetic_bay(cfg.synth);
  const Cloud c = estimate_normals(bay.sample(0.05), 20, bay.axis);
  const Grid g = build_grid(c, bay.axis, bay.profile, GridConfig{}, 1.0);
  // Every cell's TD is the 0.1 m (to the flattening and the arcs' second order).
  double worst = 0.0;
  for (int cell = 0; cell < g.size(); ++cell)
    if (g.valid[cell]) worst = std::max(worst, std::abs(g.td_m[cell] - 0.1));
  EXPECT_LT(worst, 2e-3);
  // Closed form from the section file's arcs (independent of the polyline).
  const auto v = read_section_csv(data("profiles/horseshoe.csv"));
  double length = 0.0, turning = 0.0;
  for (std::size_t i = 0; i + 1 < v.size(); ++i) {
    const double chord = std::hypot(v[i + 1].y_m - v[i].y_m, v[i + 1].z_m - v[i].z_m);
    const double angle = 4.0 * std::atan(v[i].bulge);
    length += angle == 0.0 ? chord : chord / (2.0 * std::sin(angle / 2.0)) * angle;
    turning += angle;
  }
  const double t = 0.1, bay_length = cfg.synth.length_m;
  const double expected = (length * t + turning * t * t / 2.0) * bay_length;
  // The first and last rows of cells reach past the section's ends by up to one cell.
  EXPECT_NEAR(missing_volume_m3(g), expected, 0.01 * expected);
}

TEST(Profile, SurfaceOnASectionFromTheConfig) {
  Config cfg;
  cfg.profile.section_path = data("profiles/three_centre.csv");
  cfg.synth.section_path = cfg.profile.section_path;
  cfg.synth.theta_min_rad = -0.2;
  cfg.synth.theta_max_rad = kPi + 0.2;
  const SyntheticBay bay = make_synthetic_bay(cfg.synth);
  const Surface s = build_surface(bay.sample(cfg.grid.cell_size_m), cfg);
  EXPECT_FALSE(s.profile.is_circle());
  // Cell TDs against the generator's own TD at the cell centres (noise 5 mm averaged over a cell).
  double sum2 = 0.0;
  int n = 0;
  for (int cell = 0; cell < s.grid.size(); ++cell) {
    if (!s.grid.valid[cell] || s.grid.count[cell] < 5) continue;
    const double e = s.grid.td_m[cell] - bay.td_at(s.grid.d_center(s.grid.col_of(cell)), s.grid.theta_center(s.grid.row_of(cell)));
    sum2 += e * e;
    ++n;
  }
  ASSERT_GT(n, 1000);
  EXPECT_LT(std::sqrt(sum2 / n), 0.01);
  // A bad section path is refused before any work.
  cfg.profile.section_path = data("profiles/missing.csv");
  EXPECT_THROW(build_surface(bay.sample(cfg.grid.cell_size_m), cfg), std::invalid_argument);
}

namespace {
// A horizontal curve of radius rho (centre at (0, rho, 0)) with a grade, starting at chainage 0 at
// the origin heading +x: the alignment's exact point at chainage c.
Eigen::Vector3d curve_point(double c, double rho, double grade) {
  const double a = c / rho;
  return {rho * std::sin(a), rho * (1.0 - std::cos(a)), grade * c};
}
std::vector<AlignmentPoint> curve_alignment(double rho, double grade, double from, double to, double step) {
  std::vector<AlignmentPoint> out;
  for (double c = from; c <= to + 1e-9; c += step) out.push_back({c, curve_point(c, rho, grade)});
  return out;
}
}  // namespace

TEST(Alignment, AxisOnACurveIsItsChordThroughTheScan) {
  // Radius 300 m, 2 % grade, points every metre. A scan centred 3 m above the alignment in the
  // section at chainage 125.4 m (square to the graded axis), 4 m long.
  const double rho = 300.0, grade = 0.02, c = 125.4;
  const auto a = curve_alignment(rho, grade, 0.0, 400.0, 1.0);
  const Eigen::Vector3d t0 = Eigen::Vector3d(std::cos(c / rho), std::sin(c / rho), grade).normalized();
  const Eigen::Vector3d up = (Eigen::Vector3d::UnitZ() - t0.z() * t0).normalized();
  const Eigen::Vector3d centre = curve_point(c, rho, grade) + 3.0 * up;
  const AxisOnAlignment at = axis_on_alignment(a, centre, 2.0);
  EXPECT_NEAR(at.chainage_m, c, 0.02);  // the chords of a 1 m sampling
  EXPECT_NEAR(at.scan_offset_m, 3.0, 0.01);
  // The tangent of the curve at c (horizontal heading c / rho, rising by the grade).
  const Eigen::Vector3d tangent = Eigen::Vector3d(std::cos(c / rho), std::sin(c / rho), grade).normalized();
  EXPECT_LT(std::acos(std::min(1.0, at.axis.ex.dot(tangent))), 1e-4);
  // Sagitta of a 4 m chord on 300 m: 4^2 / (8 x 300) = 6.7 mm; through the mean, about 2/3 of it
  // on one side and 1/3 on the other.
  EXPECT_GT(at.deviation_m, 0.3 * 16.0 / (8 * rho));
  EXPECT_LT(at.deviation_m, 16.0 / (8 * rho) + 1e-4);
  // The origin lies on the straight axis abreast of chainage c, within the sagitta of the curve.
  EXPECT_LT((at.axis.origin_m - curve_point(c, rho, grade)).norm(), 16.0 / (8 * rho) + 1e-4);
}

TEST(Alignment, ConfigTakesTheAxisAndTheBayRangeAsChainages) {
  const std::string path = write_temp("align.csv", [] {
    std::string t = "# a straight alignment along +y, 1 % grade\nchainage_m,x_m,y_m,z_m\n";
    for (int k = 0; k <= 100; ++k) t += std::to_string(1000.0 + k) + ",5.0," + std::to_string(200.0 + k) + "," + std::to_string(0.01 * k) + "\n";
    return t;
  }());
  Config cfg;
  cfg.profile.alignment_path = path;
  cfg.grid.bay = BaySelection::range;
  cfg.grid.bay_start_m = 1030.0;
  cfg.grid.bay_end_m = 1031.2;
  Points xyz(3, 3);
  xyz << 4.0, 229.0, 3.0, 6.0, 231.0, 3.0, 5.0, 230.0, NAN;  // centre (5, 230, 3): chainage 1030
  AxisOnAlignment at;
  const Config out = with_alignment_axis(cfg, xyz, &at);
  EXPECT_NEAR(at.chainage_m, 1030.0, 0.05);
  EXPECT_NEAR(out.profile.axis_direction.normalized().dot(Eigen::Vector3d(0, 1, 0.01).normalized()), 1.0, 1e-9);
  EXPECT_NEAR(out.grid.bay_start_m, 1030.0 - at.chainage_m, 1e-9);
  EXPECT_NEAR(out.grid.bay_end_m - out.grid.bay_start_m, 1.2, 1e-9);
  EXPECT_NEAR(at.deviation_m, 0.0, 1e-9);
  // Off the alignment, beyond its end, or a malformed file: refused by name.
  Points far(1, 3);
  far << 500.0, 230.0, 0.0;
  EXPECT_THROW(with_alignment_axis(cfg, far, nullptr), std::invalid_argument);
  Points beyond(1, 3);
  beyond << 5.0, 400.0, 0.0;
  EXPECT_THROW(with_alignment_axis(cfg, beyond, nullptr), std::invalid_argument);
  cfg.profile.alignment_path = write_temp("align_bad.csv", "0,0,0,0\n0,1,0,0\n");
  try {
    with_alignment_axis(cfg, xyz, nullptr);
    ADD_FAILURE() << "accepted a chainage that does not increase";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("line 2"), std::string::npos) << e.what();
  }
  // Without an alignment the config is unchanged.
  Config plain;
  EXPECT_EQ(with_alignment_axis(plain, xyz, nullptr).profile.axis_direction, plain.profile.axis_direction);
}
