#include "shotcrete/deposition/deposition.hpp"
#include "shotcrete/io/text.hpp"

#include <nlopt.hpp>

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>

namespace shotcrete {

namespace {

constexpr double kPi = 3.14159265358979323846;
// Physical range of a measured stroke: a pass leaves at most 1 m of concrete within +-10 m of its
// centre; anything beyond is a unit or data error (and 1e300 overflows the least squares).
constexpr double kMaxStrokeThickness_m = 1.0;
constexpr double kMaxStrokePosition_m = 10.0;

std::string format_number(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

double beta_fn(double a, double b) { return std::exp(std::lgamma(a) + std::lgamma(b) - std::lgamma(a + b)); }

void check_model(const SpotModel& m) {
  if (!(m.reference_standoff_m > 0) || !std::isfinite(m.reference_standoff_m))
    throw std::invalid_argument("spot model: reference_standoff_m must be > 0, got " + std::to_string(m.reference_standoff_m));
  if (!(m.radius_m > 0) || !std::isfinite(m.radius_m))
    throw std::invalid_argument("spot model: radius_m must be > 0, got " + std::to_string(m.radius_m));
  if (!(m.beta >= 1.0) || !std::isfinite(m.beta))
    throw std::invalid_argument("spot model: beta must be >= 1 (finite rate at the rim), got " + std::to_string(m.beta));
  if (!(m.peak_rate_mps >= 0) || !std::isfinite(m.peak_rate_mps))
    throw std::invalid_argument("spot model: peak_rate_mps must be >= 0, got " + std::to_string(m.peak_rate_mps));
}

Eigen::Vector3d unit_axis(const Eigen::Vector3d& a) {
  const double n = a.norm();
  if (!(n > 1e-12) || !std::isfinite(n)) throw std::invalid_argument("nozzle axis must be a finite non-zero vector");
  return a / n;
}

// Eq. 2-13 for d = p - nozzle, unit axis a, unit normal n (toward the nozzle side). With
// cos(theta) = t/L and cos(gamma) = -n.d/L the product (H0/L)^2 cos(gamma)/cos^3(theta) reduces to
// H0^2 (-n.d) / t^3; r_proj = H0 tan(theta) = H0 |d x a| / t.
struct RateKernel {
  Eigen::Vector3d c, a;
  double h0 = 1, h0sq = 1, r2 = 0, inv_r2 = 0, qmax = 0, expo = 0;
  RateKernel(const SpotModel& m, const NozzlePose& pose)
      : c(pose.position_m), a(unit_axis(pose.axis)) {
    h0 = m.reference_standoff_m;
    h0sq = h0 * h0;
    r2 = m.radius_m * m.radius_m;
    inv_r2 = 1.0 / r2;
    qmax = m.peak_rate_mps;
    expo = m.beta - 1.0;
  }
  double operator()(double px, double py, double pz, double nx, double ny, double nz) const {
    const double dx = px - c.x(), dy = py - c.y(), dz = pz - c.z();
    const double t = dx * a.x() + dy * a.y() + dz * a.z();
    if (t <= 0) return 0.0;  // behind the nozzle
    const double perp2 = std::max(0.0, dx * dx + dy * dy + dz * dz - t * t);
    const double rp2 = h0sq * perp2 / (t * t);
    if (rp2 >= r2) return 0.0;  // outside the cone
    const double facing = -(nx * dx + ny * dy + nz * dz);
    if (facing <= 0) return 0.0;  // gamma >= 90 deg: self-shadowed
    const double q0 = expo == 0.0 ? qmax : qmax * std::pow(1.0 - rp2 * inv_r2, expo);
    return q0 * h0sq * facing / (t * t * t);
  }
};

}  // namespace

// ---------------------------------------------------------------- spot model and stroke

double SpotModel::rate_at(double r_m) const {
  const double r = std::abs(r_m);
  if (r >= radius_m) return 0.0;
  return peak_rate_mps * std::pow(1.0 - r * r / (radius_m * radius_m), beta - 1.0);
}

double SpotModel::cone_half_angle_rad() const { return std::atan(radius_m / reference_standoff_m); }

double SpotModel::volume_rate_m3ps() const { return peak_rate_mps * kPi * radius_m * radius_m / beta; }

SpotModel spot_model_from_config(const DepositionConfig& config) {
  if (!(config.peak_rate_mps > 0))
    throw std::invalid_argument(
        "deposition.peak_rate_mps must be > 0 (got " + std::to_string(config.peak_rate_mps) +
        "); fit it with `shotcrete deposition fit data/deposition_stroke.csv` and put q_max in the config");
  SpotModel m;
  m.reference_standoff_m = config.reference_standoff_m;
  m.radius_m = config.spot_radius_m;
  m.beta = config.spot_beta;
  m.peak_rate_mps = config.peak_rate_mps;
  check_model(m);
  return m;
}

double stroke_thickness_m(const SpotModel& model, double x_m, double speed_mps) {
  if (!(speed_mps > 0)) throw std::invalid_argument("stroke: speed_mps must be > 0, got " + std::to_string(speed_mps));
  const double R = model.radius_m;
  if (std::abs(x_m) >= R) return 0.0;
  return model.peak_rate_mps / speed_mps * R * beta_fn(0.5, model.beta) *
         std::pow(1.0 - x_m * x_m / (R * R), model.beta - 0.5);
}

// ---------------------------------------------------------------- CSV

namespace {

std::string trim(const std::string& s) {
  size_t b = 0, e = s.size();
  while (b < e && std::isspace(static_cast<unsigned char>(s[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(s[e - 1]))) --e;
  return s.substr(b, e - b);
}

bool parse_number(const std::string& cell, double& out) {
  const std::string t = trim(cell);
  if (t.empty()) return false;
  char* end = nullptr;
  out = std::strtod(t.c_str(), &end);
  return end == t.c_str() + t.size() && std::isfinite(out);
}

}  // namespace

StrokeData read_stroke_csv(const std::string& path, double standoff_m, double speed_mps, double rebound_fraction) {
  if (!(standoff_m > 0)) throw std::invalid_argument("stroke: standoff must be > 0, got " + std::to_string(standoff_m));
  if (!(speed_mps > 0)) throw std::invalid_argument("stroke: speed must be > 0, got " + std::to_string(speed_mps));
  if (!(rebound_fraction >= 0 && rebound_fraction < 1))
    throw std::invalid_argument("stroke: rebound_fraction must be in [0, 1), got " + std::to_string(rebound_fraction));
  std::ifstream in(path);
  if (!in) throw std::invalid_argument("cannot open stroke CSV " + path);
  StrokeData data;
  data.standoff_m = standoff_m;
  data.speed_mps = speed_mps;
  data.rebound_fraction = rebound_fraction;
  std::string line;
  int line_no = 0;
  bool first = true;
  while (std::getline(in, line)) {
    ++line_no;
    if (trim(line).empty()) continue;
    std::vector<std::string> cells(1);
    for (char ch : line) {  // keeps empty trailing cells ("10," has an empty thickness)
      if (ch == ',') cells.emplace_back();
      else cells.back() += ch;
    }
    if (first) {
      first = false;
      double dummy;
      // A header is a first line whose first cell is text (position_mm,thickness_mm).
      if (!cells.empty() && !parse_number(cells[0], dummy) &&
          std::any_of(cells[0].begin(), cells[0].end(), [](unsigned char ch) { return std::isalpha(ch); }))
        continue;
    }
    const std::string where = "stroke CSV " + path + " line " + std::to_string(line_no) + ": ";
    if (cells.size() != 2)
      throw std::invalid_argument(where + "expected 2 columns (position_mm,thickness_mm), got " + std::to_string(cells.size()));
    double x, t;
    if (!parse_number(cells[0], x)) throw std::invalid_argument(where + "non-numeric position '" + printable(trim(cells[0])) + "'");
    if (!parse_number(cells[1], t)) throw std::invalid_argument(where + "non-numeric thickness '" + printable(trim(cells[1])) + "'");
    if (t < 0) throw std::invalid_argument(where + "negative thickness " + printable(trim(cells[1])) + " mm");
    if (std::abs(x) > kMaxStrokePosition_m * 1e3)
      throw std::invalid_argument(where + "position " + printable(trim(cells[0])) + " mm is outside the physical range +-" +
                                  std::to_string(static_cast<int>(kMaxStrokePosition_m * 1e3)) + " mm");
    if (t > kMaxStrokeThickness_m * 1e3)
      throw std::invalid_argument(where + "thickness " + printable(trim(cells[1])) + " mm is above the physical limit of " +
                                  std::to_string(static_cast<int>(kMaxStrokeThickness_m * 1e3)) + " mm");
    data.position_m.push_back(x * 1e-3);
    data.thickness_m.push_back(t * 1e-3);
  }
  if (data.position_m.size() < 5)
    throw std::invalid_argument("stroke CSV " + path + " has " + std::to_string(data.position_m.size()) +
                                " data rows; at least 5 are needed for a fit");
  if (std::all_of(data.thickness_m.begin(), data.thickness_m.end(), [](double t) { return t == 0.0; }))
    throw std::invalid_argument("stroke CSV " + path + ": all thickness values are zero");
  return data;
}

// ---------------------------------------------------------------- fit

namespace {

struct FitProblem {
  std::vector<double> x_mm, t_mm;
  int evaluations = 0;
  // SSE [mm^2] of the best amplitude for shape (R, p, x0); amplitude returned through `amp`.
  double sse(double R, double p, double x0, double* amp = nullptr) const {
    double ft = 0, ff = 0, tt = 0;
    std::vector<double> f(x_mm.size());
    for (size_t i = 0; i < x_mm.size(); ++i) {
      const double u = (x_mm[i] - x0) / R;
      f[i] = u * u < 1 ? std::pow(1 - u * u, p) : 0.0;
      ft += f[i] * t_mm[i];
      ff += f[i] * f[i];
      tt += t_mm[i] * t_mm[i];
    }
    if (ff <= 0) {
      if (amp) *amp = 0;
      return tt;
    }
    const double A = std::max(0.0, ft / ff);
    if (amp) *amp = A;
    double s = 0;
    for (size_t i = 0; i < f.size(); ++i) s += (A * f[i] - t_mm[i]) * (A * f[i] - t_mm[i]);
    return s;
  }
};

double fit_objective(const std::vector<double>& v, std::vector<double>& /*grad*/, void* data) {
  auto* pr = static_cast<FitProblem*>(data);
  ++pr->evaluations;
  return pr->sse(v[0], v[1], v[2]);
}

}  // namespace

StrokeFit fit_stroke(const StrokeData& data) {
  const size_t n = data.position_m.size();
  if (n != data.thickness_m.size()) throw std::invalid_argument("stroke: position and thickness sizes differ");
  if (n < 5) throw std::invalid_argument("stroke: at least 5 samples are needed, got " + std::to_string(n));
  if (!(data.standoff_m > 0)) throw std::invalid_argument("stroke: standoff_m must be > 0");
  if (!(data.speed_mps > 0)) throw std::invalid_argument("stroke: speed_mps must be > 0");
  if (!(data.rebound_fraction >= 0 && data.rebound_fraction < 1))
    throw std::invalid_argument("stroke: rebound_fraction must be in [0, 1)");
  FitProblem pr;
  double tsum = 0, xt = 0, tmax = 0;
  for (size_t i = 0; i < n; ++i) {
    const double x = data.position_m[i], t = data.thickness_m[i];
    if (!std::isfinite(x) || !std::isfinite(t) || t < 0)
      throw std::invalid_argument("stroke: sample " + std::to_string(i) + " (position " + format_number(x) +
                                  " m, thickness " + format_number(t) + " m) is not finite or negative");
    if (std::abs(x) > kMaxStrokePosition_m || t > kMaxStrokeThickness_m)
      throw std::invalid_argument("stroke: sample " + std::to_string(i) + " (position " + format_number(x) +
                                  " m, thickness " + format_number(t) + " m) is outside the physical range (|position| <= " +
                                  format_number(kMaxStrokePosition_m) + " m, thickness <= " +
                                  format_number(kMaxStrokeThickness_m) + " m)");
    pr.x_mm.push_back(data.position_m[i] * 1e3);  // mm keeps the problem well scaled
    pr.t_mm.push_back(data.thickness_m[i] * 1e3);
    tsum += pr.t_mm.back();
    xt += pr.x_mm.back() * pr.t_mm.back();
    tmax = std::max(tmax, pr.t_mm.back());
  }
  if (!(tmax > 0)) throw std::invalid_argument("stroke: all thickness values are zero");
  const auto [xmin_it, xmax_it] = std::minmax_element(pr.x_mm.begin(), pr.x_mm.end());
  const double half = 0.5 * (*xmax_it - *xmin_it), mid = 0.5 * (*xmax_it + *xmin_it);
  if (!(half > 0)) throw std::invalid_argument("stroke: positions must span a non-zero width");
  const double centroid = xt / tsum;

  // (R, stroke exponent p, centre x0); the amplitude is solved in closed form inside.
  const std::vector<double> lo{0.3 * half, 0.5, mid - 0.5 * half}, hi{4.0 * half, 15.0, mid + 0.5 * half};
  double best = std::numeric_limits<double>::infinity();
  std::vector<double> best_x;
  for (double r0 : {0.8, 1.0, 1.3, 2.0})
    for (double p0 : {0.7, 1.5, 3.0, 6.0}) {
      nlopt::opt opt(nlopt::LN_BOBYQA, 3);
      opt.set_lower_bounds(lo);
      opt.set_upper_bounds(hi);
      opt.set_min_objective(fit_objective, &pr);
      opt.set_xtol_rel(1e-10);
      opt.set_ftol_abs(1e-14);
      opt.set_maxeval(4000);
      std::vector<double> x{r0 * half, p0, std::clamp(centroid, lo[2], hi[2])};
      double f = 0;
      try {
        opt.optimize(x, f);
      } catch (const nlopt::roundoff_limited&) {
        f = pr.sse(x[0], x[1], x[2]);  // converged as far as doubles allow
      }
      if (std::isfinite(f) && f < best && std::all_of(x.begin(), x.end(), [](double v) { return std::isfinite(v); })) {
        best = f;
        best_x = x;
      }
    }
  if (best_x.empty())  // every start ended on a non-finite error: nothing to report
    throw std::invalid_argument("stroke: the fit found no finite error from any start (" +
                                std::to_string(pr.evaluations) + " evaluations); check the stroke data");
  double amp_mm = 0;
  best = pr.sse(best_x[0], best_x[1], best_x[2], &amp_mm);

  StrokeFit fit;
  fit.speed_mps = data.speed_mps;
  fit.rebound_fraction = data.rebound_fraction;
  fit.evaluations = pr.evaluations;
  fit.center_offset_m = best_x[2] * 1e-3;
  fit.stroke_exponent = best_x[1];
  fit.mse_mm2 = best / static_cast<double>(n);
  fit.peak_thickness_m = amp_mm * 1e-3;
  SpotModel& m = fit.model;
  m.reference_standoff_m = data.standoff_m;
  m.radius_m = best_x[0] * 1e-3;
  m.beta = best_x[1] + 0.5;
  // Peak of the deposited stroke A = (q_dep / v) R B(1/2, beta); sprayed q = q_dep / (1 - rebound).
  const double q_dep = fit.peak_thickness_m * data.speed_mps / (m.radius_m * beta_fn(0.5, m.beta));
  m.peak_rate_mps = q_dep / (1.0 - data.rebound_fraction);
  fit.flow_m3ph = m.volume_rate_m3ps() * 3600.0;
  fit.deposited_flow_m3ph = fit.flow_m3ph * (1.0 - data.rebound_fraction);
  return fit;
}

double StrokeFit::stroke_at_m(double x_m) const {
  return stroke_thickness_m(model, x_m - center_offset_m, speed_mps) * (1.0 - rebound_fraction);
}

// ---------------------------------------------------------------- point rate

double point_rate_mps(const SpotModel& model, const NozzlePose& nozzle, const Eigen::Vector3d& p,
                      const Eigen::Vector3d& n) {
  check_model(model);
  const double nn = n.norm();
  if (!(nn > 1e-12)) throw std::invalid_argument("point_rate_mps: normal must be non-zero");
  const RateKernel k(model, nozzle);
  const Eigen::Vector3d u = n / nn;
  return k(p.x(), p.y(), p.z(), u.x(), u.y(), u.z());
}

// ---------------------------------------------------------------- spatial index

// A dense voxel grid over the cloud's bounding box with the points sorted by voxel (counting
// sort): a query visits only the voxels overlapping its ball, and their points are contiguous.
struct SurfaceIndex::Impl {
  Cloud cloud;
  double cell = 0.05;
  Eigen::Vector3d lo;
  std::array<long, 3> dims{1, 1, 1};
  std::vector<int> start;  // per voxel, offset into order/xyz_sorted; size voxels + 1
  std::vector<int> order;  // sorted position -> point index
  std::vector<double> xyz, nrm;  // sorted copies, 3 per point

  long voxel(long i, long j, long k) const { return (k * dims[1] + j) * dims[0] + i; }
  long coord(double v, int axis) const {
    return std::clamp(static_cast<long>(std::floor((v - lo[axis]) / cell)), 0L, dims[axis] - 1);
  }

  template <class F> void visit_ball(const Eigen::Vector3d& c, double r, F&& f) const {
    if (!(r > 0)) return;
    long i0 = static_cast<long>(std::floor((c.x() - r - lo.x()) / cell));
    long i1 = static_cast<long>(std::floor((c.x() + r - lo.x()) / cell));
    long j0 = static_cast<long>(std::floor((c.y() - r - lo.y()) / cell));
    long j1 = static_cast<long>(std::floor((c.y() + r - lo.y()) / cell));
    long k0 = static_cast<long>(std::floor((c.z() - r - lo.z()) / cell));
    long k1 = static_cast<long>(std::floor((c.z() + r - lo.z()) / cell));
    i0 = std::max(i0, 0L), j0 = std::max(j0, 0L), k0 = std::max(k0, 0L);
    i1 = std::min(i1, dims[0] - 1), j1 = std::min(j1, dims[1] - 1), k1 = std::min(k1, dims[2] - 1);
    const double r2 = r * r;
    for (long k = k0; k <= k1; ++k) {
      const double z0 = lo.z() + k * cell;
      const double dz = std::max({z0 - c.z(), 0.0, c.z() - z0 - cell});
      for (long j = j0; j <= j1; ++j) {
        const double y0 = lo.y() + j * cell;
        const double dy = std::max({y0 - c.y(), 0.0, c.y() - y0 - cell});
        if (dy * dy + dz * dz > r2) continue;
        // The voxels of a row that meet the ball are a run, and so are their points (sorted by
        // voxel, x fastest): one call per row.
        const double half = std::sqrt(r2 - dy * dy - dz * dz);
        const long a = std::max(i0, static_cast<long>(std::floor((c.x() - half - lo.x()) / cell)));
        const long z = std::min(i1, static_cast<long>(std::floor((c.x() + half - lo.x()) / cell)));
        if (a > z) continue;
        const long row = voxel(0, j, k);
        const int b = start[row + a], e = start[row + z + 1];
        if (b < e) f(b, e, a, z, j, k);
      }
    }
  }

  // visit_ball, less the voxels that lie wholly outside the cone from apex c along unit axis a
  // with half-angle alpha (cos_a, sin_a): a voxel's points are within its half diagonal of its
  // centre, and a centre farther than that from the cone leaves every point outside it, where
  // the spray kernel is 0 anyway. The runs of the voxels kept are visited as before.
  template <class F>
  void visit_ball_in_cone(const Eigen::Vector3d& center, double r, const Eigen::Vector3d& c, const Eigen::Vector3d& a,
                          double cos_a, double sin_a, F&& f) const {
    // Plus the rounding of coordinates as large as the box's (survey coordinates run to 1e7 m).
    const double far_m = lo.cwiseAbs().maxCoeff() + cell * static_cast<double>(std::max({dims[0], dims[1], dims[2]}));
    const double rho = 0.5 * std::sqrt(3.0) * cell * (1.0 + 1e-9) + 1e-9 + 1e-14 * far_m;
    auto outside = [&](long i, long j, long k) {
      const Eigen::Vector3d v = lo + cell * Eigen::Vector3d(i + 0.5, j + 0.5, k + 0.5) - c;
      const double t = v.dot(a), perp = std::sqrt(std::max(0.0, v.squaredNorm() - t * t));
      // Distance from v to the cone: to its surface, or to the apex where v lies behind it.
      const double dist = t * cos_a + perp * sin_a <= 0 ? v.norm() : perp * cos_a - t * sin_a;
      return dist > rho;
    };
    visit_ball(center, r, [&](int, int, long a0, long a1, long j, long k) {
      const long row = voxel(0, j, k);
      long run = -1;  // first voxel of the run of kept voxels being gathered
      for (long i = a0; i <= a1 + 1; ++i) {
        const bool keep = i <= a1 && !outside(i, j, k);
        if (keep && run < 0) run = i;
        if (keep || run < 0) continue;
        const int b = start[row + run], e = start[row + i];
        if (b < e) f(b, e);
        run = -1;
      }
    });
  }
};

SurfaceIndex::SurfaceIndex(const Cloud& cloud, double cell_size_m) : impl_(std::make_unique<Impl>()) {
  if (cloud.size() == 0) throw std::invalid_argument("SurfaceIndex: the cloud is empty");
  if (!cloud.has_normals()) throw std::invalid_argument("SurfaceIndex: the cloud needs one normal per point");
  if (!(cell_size_m > 0) || !std::isfinite(cell_size_m))
    throw std::invalid_argument("SurfaceIndex: cell_size_m must be > 0, got " + std::to_string(cell_size_m));
  if (cloud.size() >= std::numeric_limits<int>::max()) throw std::invalid_argument("SurfaceIndex: too many points");
  Impl& m = *impl_;
  m.cloud = cloud;
  for (Eigen::Index i = 0; i < cloud.size(); ++i) {
    if (!cloud.xyz.row(i).allFinite()) throw std::invalid_argument("SurfaceIndex: point " + std::to_string(i) + " is not finite");
    const double nn = cloud.normals.row(i).norm();
    if (!(nn > 1e-9) || !std::isfinite(nn))
      throw std::invalid_argument("SurfaceIndex: normal " + std::to_string(i) + " is zero or not finite");
    m.cloud.normals.row(i) /= nn;
  }
  m.lo = cloud.xyz.colwise().minCoeff().transpose();
  const Eigen::Vector3d ext = cloud.xyz.colwise().maxCoeff().transpose() - m.lo;
  m.cell = cell_size_m;
  // Cap the dense grid at 8M voxels (32 MB of offsets): coarser voxels for huge extents.
  for (;;) {
    long total = 1;
    for (int a = 0; a < 3; ++a) {
      m.dims[a] = static_cast<long>(std::floor(ext[a] / m.cell)) + 1;
      total *= m.dims[a];
    }
    if (total <= 8'000'000) break;
    m.cell *= 1.25;
  }
  const long voxels = m.dims[0] * m.dims[1] * m.dims[2];
  const int n = static_cast<int>(cloud.size());
  std::vector<long> vox(n);
  m.start.assign(voxels + 1, 0);
  for (int i = 0; i < n; ++i) {
    const auto p = m.cloud.xyz.row(i);
    vox[i] = m.voxel(m.coord(p(0), 0), m.coord(p(1), 1), m.coord(p(2), 2));
    ++m.start[vox[i] + 1];
  }
  for (long v = 0; v < voxels; ++v) m.start[v + 1] += m.start[v];
  std::vector<int> fill(m.start.begin(), m.start.end() - 1);
  m.order.resize(n);
  for (int i = 0; i < n; ++i) m.order[fill[vox[i]]++] = i;
  m.xyz.resize(3 * static_cast<size_t>(n));
  m.nrm.resize(3 * static_cast<size_t>(n));
  for (int s = 0; s < n; ++s)
    for (int a = 0; a < 3; ++a) {
      m.xyz[3 * s + a] = m.cloud.xyz(m.order[s], a);
      m.nrm[3 * s + a] = m.cloud.normals(m.order[s], a);
    }
}

SurfaceIndex::~SurfaceIndex() = default;
SurfaceIndex::SurfaceIndex(SurfaceIndex&&) noexcept = default;
SurfaceIndex& SurfaceIndex::operator=(SurfaceIndex&&) noexcept = default;
const Cloud& SurfaceIndex::cloud() const { return impl_->cloud; }
double SurfaceIndex::cell_size_m() const { return impl_->cell; }

void SurfaceIndex::within(const Eigen::Vector3d& center, double radius_m, std::vector<int>& out) const {
  out.clear();
  const double r2 = radius_m * radius_m;
  const Impl& m = *impl_;
  m.visit_ball(center, radius_m, [&](int b, int e, long, long, long, long) {
    for (int s = b; s < e; ++s) {
      const double dx = m.xyz[3 * s] - center.x(), dy = m.xyz[3 * s + 1] - center.y(), dz = m.xyz[3 * s + 2] - center.z();
      if (dx * dx + dy * dy + dz * dz <= r2) out.push_back(m.order[s]);
    }
  });
  std::sort(out.begin(), out.end());
}

// The reachable points lie on the first surface along the spray axis. March along the axis
// through the voxels (half-voxel steps) to the first occupied voxel: the axis meets the surface at
// a distance D within one voxel diagonal. On a plane whose normal makes phi with the axis the cone
// footprint reaches D sin(alpha) / cos(phi + alpha) from the axis hit point (the far rim); the ball
// takes that with D widened by a voxel diagonal, x1.2 and two voxels for curvature, roughness and
// the error of the hit. If the axis meets no point, or grazes (phi + alpha > 80 deg), the ball
// encloses the whole cone up to the far corner of the bounding box (slower, still exact).
std::pair<Eigen::Vector3d, double> SurfaceIndex::reach_ball(const SpotModel& model, const NozzlePose& nozzle) const {
  check_model(model);
  const Impl& m = *impl_;
  const Eigen::Vector3d a = unit_axis(nozzle.axis), c = nozzle.position_m;
  if (!c.allFinite()) throw std::invalid_argument("nozzle position is not finite");
  const double tan_a = model.radius_m / model.reference_standoff_m, alpha = std::atan(tan_a);
  const Eigen::Vector3d hi = m.lo + m.cell * Eigen::Vector3d(m.dims[0], m.dims[1], m.dims[2]);
  double t_far = 0;
  for (int corner = 0; corner < 8; ++corner) {
    const Eigen::Vector3d q((corner & 1) ? hi.x() : m.lo.x(), (corner & 2) ? hi.y() : m.lo.y(), (corner & 4) ? hi.z() : m.lo.z());
    t_far = std::max(t_far, (q - c).dot(a));
  }
  if (t_far <= 0) return {c, 0.0};  // the whole cloud is behind the nozzle
  // Slab intersection of the axis ray with the box.
  double t0 = 0, t1 = t_far;
  for (int k = 0; k < 3; ++k) {
    if (std::abs(a[k]) < 1e-15) {
      if (c[k] < m.lo[k] || c[k] > hi[k]) t1 = -1;
      continue;
    }
    double ta = (m.lo[k] - c[k]) / a[k], tb = (hi[k] - c[k]) / a[k];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  const double diag = std::sqrt(3.0) * m.cell;
  for (double t = t0; t <= t1; t += 0.5 * m.cell) {
    const Eigen::Vector3d p = c + t * a;
    const long v = m.voxel(m.coord(p.x(), 0), m.coord(p.y(), 1), m.coord(p.z(), 2));
    const int b = m.start[v], e = m.start[v + 1];
    if (b == e) continue;
    Eigen::Vector3d nsum = Eigen::Vector3d::Zero();
    for (int s = b; s < e; ++s) nsum += Eigen::Vector3d(m.nrm[3 * s], m.nrm[3 * s + 1], m.nrm[3 * s + 2]);
    const double nn = nsum.norm();
    const double phi = nn > 1e-9 ? std::acos(std::clamp(-a.dot(nsum / nn), -1.0, 1.0)) : kPi;
    if (phi + alpha > 80.0 * kPi / 180.0) break;  // grazing or facing away: use the cone ball
    const double rim = (t + diag) * std::sin(alpha) / std::cos(phi + alpha);
    return {p, 1.2 * rim + 2.0 * diag};
  }
  // Smallest ball through the apex enclosing the cone truncated at t_far.
  const double rho = t_far * tan_a, tc = (t_far * t_far + rho * rho) / (2.0 * t_far);
  return {c + tc * a, tc * (1.0 + 1e-9) + 1e-9};
}

// Into a buffer in the index's voxel order: the visited points are contiguous there, so the
// writes stream instead of scattering over the whole cloud.
void SurfaceIndex::add_rates_sorted(const SpotModel& model, const NozzlePose& nozzle, double weight, double* sorted) const {
  const Impl& m = *impl_;
  const auto [center, radius] = reach_ball(model, nozzle);
  const RateKernel k(model, nozzle);
  const double alpha = model.cone_half_angle_rad();
  m.visit_ball_in_cone(center, radius, k.c, k.a, std::cos(alpha), std::sin(alpha), [&](int b, int e) {
    for (int s = b; s < e; ++s) {
      const double* p = &m.xyz[3 * s];
      const double* n = &m.nrm[3 * s];
      const double q = k(p[0], p[1], p[2], n[0], n[1], n[2]);
      if (q > 0) sorted[s] += q * weight;
    }
  });
}

void SurfaceIndex::add_sorted(const std::vector<double>& sorted, Eigen::VectorXd& out) const {
  const Impl& m = *impl_;
  for (std::size_t s = 0; s < sorted.size(); ++s) out[m.order[s]] += sorted[s];
}

// ---------------------------------------------------------------- accumulation

void accumulate_dwells(const SpotModel& model, const SurfaceIndex& surface, const std::vector<NozzlePose>& poses,
                       const std::vector<double>& dwell_s, double rebound_fraction, Eigen::VectorXd& thickness_m) {
  check_model(model);
  if (poses.size() != dwell_s.size())
    throw std::invalid_argument("accumulate_dwells: " + std::to_string(poses.size()) + " poses but " +
                                std::to_string(dwell_s.size()) + " dwell times");
  if (!(rebound_fraction >= 0 && rebound_fraction < 1))
    throw std::invalid_argument("rebound_fraction must be in [0, 1), got " + std::to_string(rebound_fraction));
  const Eigen::Index n = surface.cloud().size();
  if (thickness_m.size() == 0) thickness_m = Eigen::VectorXd::Zero(n);
  if (thickness_m.size() != n)
    throw std::invalid_argument("thickness vector has " + std::to_string(thickness_m.size()) + " entries, the cloud " +
                                std::to_string(n));
  std::vector<std::size_t> todo;  // checked here so the parallel loop below cannot throw
  for (size_t i = 0; i < poses.size(); ++i) {
    if (!(dwell_s[i] >= 0) || !std::isfinite(dwell_s[i]))
      throw std::invalid_argument("dwell time " + std::to_string(i) + " must be finite and >= 0");
    if (dwell_s[i] == 0) continue;
    if (!poses[i].position_m.allFinite()) throw std::invalid_argument("nozzle position is not finite");
    unit_axis(poses[i].axis);
    todo.push_back(i);
  }
  // A fixed number of contiguous chunks, each with its own buffer, summed in chunk order: the
  // result does not depend on how many threads ran them. Fewer chunks on huge clouds (memory).
  const long per_chunk_min = 256;
  long chunks = std::min<long>(8, (static_cast<long>(todo.size()) + per_chunk_min - 1) / per_chunk_min);
  if (n > 2'000'000) chunks = std::min<long>(chunks, 2);
  chunks = std::max<long>(chunks, 1);
  std::vector<std::vector<double>> buffers(static_cast<std::size_t>(chunks));
  const double keep = 1.0 - rebound_fraction;
#pragma omp parallel for schedule(dynamic, 1) if (chunks > 1)
  for (long c = 0; c < chunks; ++c) {
    std::vector<double>& buf = buffers[static_cast<std::size_t>(c)];
    buf.assign(static_cast<std::size_t>(n), 0.0);
    const std::size_t b = todo.size() * static_cast<std::size_t>(c) / static_cast<std::size_t>(chunks);
    const std::size_t e = todo.size() * static_cast<std::size_t>(c + 1) / static_cast<std::size_t>(chunks);
    for (std::size_t j = b; j < e; ++j) surface.add_rates_sorted(model, poses[todo[j]], dwell_s[todo[j]] * keep, buf.data());
  }
  for (const auto& buf : buffers) surface.add_sorted(buf, thickness_m);
}

PassSamples resample_pass(const std::vector<NozzlePose>& polyline, double speed_mps, double step_m) {
  if (polyline.size() < 2) throw std::invalid_argument("a pass needs at least 2 poses, got " + std::to_string(polyline.size()));
  if (!(speed_mps > 0) || !std::isfinite(speed_mps))
    throw std::invalid_argument("pass speed_mps must be > 0, got " + std::to_string(speed_mps));
  if (!(step_m > 0) || !std::isfinite(step_m)) throw std::invalid_argument("pass step_m must be > 0, got " + std::to_string(step_m));
  std::vector<double> cum{0.0};
  std::vector<Eigen::Vector3d> axes;
  for (size_t i = 0; i < polyline.size(); ++i) {
    if (!polyline[i].position_m.allFinite()) throw std::invalid_argument("pass pose " + std::to_string(i) + " is not finite");
    axes.push_back(unit_axis(polyline[i].axis));
    if (i > 0) cum.push_back(cum.back() + (polyline[i].position_m - polyline[i - 1].position_m).norm());
  }
  PassSamples out;
  out.length_m = cum.back();
  if (!(out.length_m > 0)) throw std::invalid_argument("pass has zero length (all poses at one position)");
  const double nd = std::ceil(out.length_m / step_m - 1e-9);
  if (nd > 1e7) throw std::invalid_argument("pass step_m too small for the pass length (over 1e7 samples)");
  const long n = std::max(1L, static_cast<long>(nd));
  const double h = out.length_m / static_cast<double>(n);
  size_t j = 0;
  for (long k = 0; k < n; ++k) {
    const double s = (static_cast<double>(k) + 0.5) * h;
    while (j + 2 < cum.size() && cum[j + 1] < s) ++j;
    const double len = cum[j + 1] - cum[j];
    const double u = len > 0 ? std::clamp((s - cum[j]) / len, 0.0, 1.0) : 0.0;
    NozzlePose p;
    p.position_m = (1 - u) * polyline[j].position_m + u * polyline[j + 1].position_m;
    const Eigen::Vector3d ax = (1 - u) * axes[j] + u * axes[j + 1];
    if (!(ax.norm() > 1e-9)) throw std::invalid_argument("pass axes of poses " + std::to_string(j) + " and " +
                                                         std::to_string(j + 1) + " are opposite");
    p.axis = ax.normalized();
    out.poses.push_back(p);
    out.dwell_s.push_back(h / speed_mps);
  }
  return out;
}

void accumulate_pass(const SpotModel& model, const SurfaceIndex& surface, const std::vector<NozzlePose>& polyline,
                     double speed_mps, double step_m, double rebound_fraction, Eigen::VectorXd& thickness_m) {
  const PassSamples s = resample_pass(polyline, speed_mps, step_m);
  accumulate_dwells(model, surface, s.poses, s.dwell_s, rebound_fraction, thickness_m);
}

// ---------------------------------------------------------------- pass spacing

namespace {

struct SpacingEval {
  double R, expo, td, dx = 1e-3;
  double shape(double x) const {
    const double u = x / R;
    return u * u < 1 ? std::pow(1 - u * u, expo) : 0.0;
  }
  // Sum over the 1 mm grid between the two pass centres (x = 0 and x = s).
  double cost(double overlap, double* band_min = nullptr, double* band_max = nullptr) const {
    const double s = 2 * R - overlap;
    const long n = static_cast<long>(std::floor(s / dx + 1e-9));
    double j = 0, lo = std::numeric_limits<double>::infinity(), hi = -lo;
    for (long k = 0; k <= n; ++k) {
      const double x = k * dx;
      const double t = td * (shape(x) + shape(x - s));
      j += (td - t) * (td - t);
      lo = std::min(lo, t);
      hi = std::max(hi, t);
    }
    if (band_min) *band_min = lo;
    if (band_max) *band_max = hi;
    return j;
  }
  double golden(double a, double b) const {
    const double g = 0.5 * (std::sqrt(5.0) - 1.0);
    double c = b - g * (b - a), d = a + g * (b - a), fc = cost(c), fd = cost(d);
    while (b - a > 1e-6) {
      if (fc < fd) {
        b = d, d = c, fd = fc;
        c = b - g * (b - a), fc = cost(c);
      } else {
        a = c, c = d, fc = fd;
        d = a + g * (b - a), fd = cost(d);
      }
    }
    return 0.5 * (a + b);
  }
};

}  // namespace

PassSpacing pass_spacing(const SpotModel& model, double target_thickness_m) {
  check_model(model);
  if (!(target_thickness_m > 0) || !std::isfinite(target_thickness_m))
    throw std::invalid_argument("pass_spacing: target thickness must be > 0, got " + std::to_string(target_thickness_m));
  const SpacingEval ev{model.radius_m, model.beta - 0.5, target_thickness_m};
  const double R = model.radius_m;
  double o = ev.golden(0.0, R);
  if (o > R - 1e-4) o = ev.golden(R, 2.0 * R - ev.dx);  // optimum on the design bound: widen
  PassSpacing out;
  out.overlap_m = o;
  out.spacing_m = 2 * R - o;
  ev.cost(o, &out.band_min_m, &out.band_max_m);
  return out;
}

double line_ripple(const SpotModel& model, double pitch_m) {
  check_model(model);
  if (!(pitch_m >= 1e-3 * model.radius_m) || !std::isfinite(pitch_m))
    throw std::invalid_argument("line_ripple: the pitch must be finite and >= 0.001 of the spot radius (" +
                                std::to_string(model.radius_m) + " m), got " + std::to_string(pitch_m) + " m");
  const SpacingEval ev{model.radius_m, model.beta - 0.5, 1.0};
  // The sum is periodic in the pitch: sample one period, with every stroke that reaches it.
  const int reach = static_cast<int>(std::ceil(model.radius_m / pitch_m)) + 1;
  constexpr int kSamples = 400;
  double lo = std::numeric_limits<double>::infinity(), hi = -lo, sum = 0;
  for (int i = 0; i < kSamples; ++i) {
    const double x = pitch_m * i / kSamples;
    double t = 0;
    for (int k = -reach; k <= reach; ++k) t += ev.shape(x - k * pitch_m);
    lo = std::min(lo, t);
    hi = std::max(hi, t);
    sum += t;
  }
  return (hi - lo) / (sum / kSamples);
}

LinePitch least_ripple_pitch(const SpotModel& model, double lo_m, double hi_m) {
  check_model(model);
  // Lines closer than 5 % of the spot's radius are no spray pattern (and each ripple would sum
  // over 40+ strokes).
  if (!(lo_m >= 0.05 * model.radius_m) || !(hi_m >= lo_m) || !std::isfinite(hi_m))
    throw std::invalid_argument("least_ripple_pitch: need 0.05 R (" + std::to_string(0.05 * model.radius_m) +
                                " m) <= lo <= hi, got [" + std::to_string(lo_m) + ", " + std::to_string(hi_m) + "] m");
  // 0.1 mm, finer for a small spot's pitch (0.2 % of the window's low end below 50 mm), and at
  // most 2e4 steps (coarser only for windows over 2 m).
  const double step_m = std::max(std::min(1e-4, 2e-3 * lo_m), (hi_m - lo_m) / 2e4);
  const int n = static_cast<int>(std::floor((hi_m - lo_m) / step_m + 1e-9));
  LinePitch best{lo_m, line_ripple(model, lo_m)};
  for (int i = 1; i <= n + 1; ++i) {
    const double p = i <= n ? lo_m + i * step_m : hi_m;
    const double r = line_ripple(model, p);
    if (r < best.ripple) best = {p, r};
  }
  return best;
}

}  // namespace shotcrete
