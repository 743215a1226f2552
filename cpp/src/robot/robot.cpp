// The manipulator model: URDF loading (with the acceleration limits and the neutral posture of
// <shotcrete:limits>), forward kinematics and the geometric Jacobian in the tunnel frame.
#include "shotcrete/robot/robot.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>
#include <stdexcept>

#include <kdl/tree.hpp>
#include <kdl_parser/kdl_parser.hpp>
#include <urdf/model.h>

#include "detail.hpp"

namespace shotcrete {

namespace robot_detail {

KDL::JntArray to_kdl(const Eigen::VectorXd& q) {
  KDL::JntArray a(static_cast<unsigned>(q.size()));
  a.data = q;
  return a;
}

KDL::Frame to_kdl(const Eigen::Isometry3d& t) {
  KDL::Frame f;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) f.M(r, c) = t.linear()(r, c);
    f.p(r) = t.translation()(r);
  }
  return f;
}

void check_q(const Robot& robot, const Eigen::VectorXd& q, const char* what) {
  if (q.size() != robot.dof())
    throw std::invalid_argument(std::string(what) + " has " + std::to_string(q.size()) + " entries, the robot has " +
                                std::to_string(robot.dof()) + " joints");
  if (!q.allFinite()) throw std::invalid_argument(std::string(what) + " contains NaN or inf");
}

double axis_angle(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

}  // namespace robot_detail

using namespace robot_detail;

namespace {

// A URDF <origin> (or a joint's) as an isometry.
Eigen::Isometry3d to_isometry(const urdf::Pose& o) {
  double qx, qy, qz, qw;
  o.rotation.getQuaternion(qx, qy, qz, qw);
  return Eigen::Translation3d(o.position.x, o.position.y, o.position.z) * Eigen::Quaterniond(qw, qx, qy, qz);
}

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::invalid_argument("cannot open URDF file '" + path + "'");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Acceleration limits live in <shotcrete:limits joint=".." acceleration=".."/> elements, which URDF
// parsers ignore; a regex over the flat, attribute-only element is all that is needed.
struct ExtraLimits {
  double acceleration = 0.0;
  double neutral = NAN;  // optional ready posture; NaN = mid-range
  double stow = NAN;     // optional posture a job starts from; NaN = neutral
};

double parse_number(const std::string& joint, const char* what, const std::string& text) {
  try {
    size_t used = 0;
    const double v = std::stod(text, &used);
    if (used != text.size() || !std::isfinite(v)) throw std::invalid_argument("bad");
    return v;
  } catch (const std::exception&) {
    throw std::invalid_argument("URDF: " + std::string(what) + " of joint '" + joint + "' is not a number: '" + text + "'");
  }
}

std::map<std::string, ExtraLimits> parse_extra_limits(const std::string& text) {
  std::map<std::string, ExtraLimits> out;
  static const std::regex comment(R"(<!--[\s\S]*?-->)");
  const std::string xml = std::regex_replace(text, comment, "");
  static const std::regex elem(R"(<shotcrete:limits\b([^>]*)/?>)");
  static const std::regex attr(R"re((\w+)\s*=\s*"([^"]*)")re");
  for (auto it = std::sregex_iterator(xml.begin(), xml.end(), elem); it != std::sregex_iterator(); ++it) {
    const std::string body = (*it)[1].str();
    std::string joint, acc, neutral, stow;
    for (auto a = std::sregex_iterator(body.begin(), body.end(), attr); a != std::sregex_iterator(); ++a) {
      if ((*a)[1] == "joint") joint = (*a)[2];
      if ((*a)[1] == "acceleration") acc = (*a)[2];
      if ((*a)[1] == "neutral") neutral = (*a)[2];
      if ((*a)[1] == "stow") stow = (*a)[2];
    }
    if (joint.empty() || acc.empty())
      throw std::invalid_argument("URDF: <shotcrete:limits> needs joint=\"..\" and acceleration=\"..\"");
    ExtraLimits e;
    e.acceleration = parse_number(joint, "acceleration limit", acc);
    if (!(e.acceleration > 0.0)) throw std::invalid_argument("URDF: acceleration limit of joint '" + joint + "' must be > 0");
    if (!neutral.empty()) e.neutral = parse_number(joint, "neutral position", neutral);
    if (!stow.empty()) e.stow = parse_number(joint, "stow position", stow);
    out[joint] = e;
  }
  return out;
}

Eigen::Isometry3d to_eigen(const KDL::Frame& f) {
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) t.linear()(r, c) = f.M(r, c);
    t.translation()(r) = f.p(r);
  }
  return t;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Robot

std::string bundled_urdf_path() { return std::string(SHOTCRETE_SOURCE_DIR) + "/data/shotcrete_manipulator.urdf"; }

Robot::Robot() : impl_(std::make_unique<Impl>()) {}
Robot::Robot(const Robot& o) : impl_(std::make_unique<Impl>(*o.impl_)) {}
Robot& Robot::operator=(const Robot& o) {
  if (this != &o) impl_ = std::make_unique<Impl>(*o.impl_);
  return *this;
}
Robot::Robot(Robot&&) noexcept = default;
Robot& Robot::operator=(Robot&&) noexcept = default;
Robot::~Robot() = default;

Robot Robot::load(const RobotConfig& config) {
  return load_file(config.urdf_path.empty() ? bundled_urdf_path() : config.urdf_path, config.base_position_m);
}

Robot Robot::load_file(const std::string& urdf_path, const Eigen::Vector3d& base_position_m) {
  Robot r = from_string(read_text(urdf_path), base_position_m);
  r.impl_->path = urdf_path;
  return r;
}

Robot Robot::from_string(const std::string& xml, const Eigen::Vector3d& base_position_m) {
  if (!base_position_m.allFinite()) throw std::invalid_argument("robot.base_position_m contains NaN or inf");
  urdf::Model model;
  if (!model.initString(xml)) throw std::invalid_argument("URDF: cannot parse the robot description");
  KDL::Tree tree;
  if (!kdl_parser::treeFromUrdfModel(model, tree)) throw std::invalid_argument("URDF: kdl_parser cannot build a tree");
  Robot robot;
  Impl& im = *robot.impl_;
  if (!tree.getChain("base_link", "nozzle_tip", im.chain))
    throw std::invalid_argument("URDF: no kinematic chain from base_link to nozzle_tip");
  for (const auto& seg : im.chain.segments) im.segment_tip.push_back(seg.getJoint().pose(0.0).Inverse() * seg.getFrameToTip());
  const auto acc = parse_extra_limits(xml);
  const int n = static_cast<int>(im.chain.getNrOfJoints());
  if (n < 5) throw std::invalid_argument("URDF: the chain has " + std::to_string(n) + " joints; a 5-DOF task needs >= 5");
  im.lower.resize(n);
  im.upper.resize(n);
  im.velocity.resize(n);
  im.acceleration.resize(n);
  im.neutral.resize(n);
  im.stow.resize(n);
  int j = 0;
  bool past_first = false;
  for (const auto& seg : im.chain.segments) {
    const KDL::Joint& kj = seg.getJoint();
    if (kj.getType() == KDL::Joint::None) {
      if (past_first) im.max_reach_m += seg.getFrameToTip().p.Norm();
      continue;
    }
    const std::string name = kj.getName();
    const auto uj = model.getJoint(name);
    if (!uj || !uj->limits || uj->type == urdf::Joint::CONTINUOUS)
      throw std::invalid_argument("URDF: joint '" + name + "' needs <limit lower upper velocity> (no continuous joints)");
    const auto it = acc.find(name);
    if (it == acc.end())
      throw std::invalid_argument("URDF: joint '" + name + "' has no <shotcrete:limits acceleration=..> element");
    if (!(uj->limits->upper > uj->limits->lower))
      throw std::invalid_argument("URDF: joint '" + name + "' has upper limit <= lower limit");
    if (!(uj->limits->velocity > 0)) throw std::invalid_argument("URDF: joint '" + name + "' needs a velocity limit > 0");
    im.names.push_back(name);
    im.prismatic.push_back(uj->type == urdf::Joint::PRISMATIC);
    im.lower(j) = uj->limits->lower;
    im.upper(j) = uj->limits->upper;
    im.velocity(j) = uj->limits->velocity;
    im.acceleration(j) = it->second.acceleration;
    im.neutral(j) = std::isnan(it->second.neutral) ? 0.5 * (im.lower(j) + im.upper(j)) : it->second.neutral;
    if (im.neutral(j) < im.lower(j) || im.neutral(j) > im.upper(j))
      throw std::invalid_argument("URDF: neutral position of joint '" + name + "' is outside its limits");
    im.stow(j) = std::isnan(it->second.stow) ? im.neutral(j) : it->second.stow;
    if (im.stow(j) < im.lower(j) || im.stow(j) > im.upper(j))
      throw std::invalid_argument("URDF: stow position of joint '" + name + "' is outside its limits");
    // Reach bound measured from the first joint's origin: every later offset plus full strokes.
    // Each segment's tip is the next joint origin, so the offsets after the first joint bound
    // the distance from that joint's origin (triangle inequality).
    if (past_first) im.max_reach_m += seg.getFrameToTip().p.Norm();
    past_first = true;
    if (im.prismatic.back()) im.max_reach_m += std::max(std::abs(im.lower(j)), std::abs(im.upper(j)));
    ++j;
  }
  // First joint origin in base_link: the tip frame of its segment at q = 0 (joint origins coincide
  // with segment tips in kdl_parser's trees, up to the joint's own motion).
  {
    KDL::Frame f = KDL::Frame::Identity();
    for (const auto& seg : im.chain.segments) {
      f = f * seg.pose(0.0);
      if (seg.getJoint().getType() != KDL::Joint::None) break;
    }
    im.shoulder_in_base = Eigen::Vector3d(f.p.x(), f.p.y(), f.p.z());
  }
  for (const auto& [name, value] : acc) {
    (void)value;
    if (std::find(im.names.begin(), im.names.end(), name) == im.names.end())
      throw std::invalid_argument("URDF: <shotcrete:limits> names unknown joint '" + name + "'");
  }
  im.base = Eigen::Isometry3d::Identity();
  im.base.translation() = base_position_m;
  // Collision geometry of base_link and of each segment's link (kdl_parser names segments after
  // their child links).
  im.link_names.push_back("base_link");
  for (const auto& seg : im.chain.segments) im.link_names.push_back(seg.getName());
  // A <collision> of `link` as a shape on frame `frame`, `in_frame` placing the link in that frame.
  const auto add_shapes = [&](const urdf::LinkConstSharedPtr& link, int frame, const Eigen::Isometry3d& in_frame, bool carrier) {
    for (const auto& col : link->collision_array) {
      if (!col || !col->geometry) continue;
      CollisionShape s;
      s.link = link->name;
      s.frame = frame;
      s.carrier = carrier;
      s.origin = in_frame * to_isometry(col->origin);
      switch (col->geometry->type) {
        case urdf::Geometry::CYLINDER: {
          const auto* c = static_cast<const urdf::Cylinder*>(col->geometry.get());
          s.kind = CollisionShape::Kind::cylinder, s.radius_m = c->radius, s.length_m = c->length;
          break;
        }
        case urdf::Geometry::BOX: {
          const auto* b = static_cast<const urdf::Box*>(col->geometry.get());
          s.kind = CollisionShape::Kind::box, s.size_m = Eigen::Vector3d(b->dim.x, b->dim.y, b->dim.z);
          break;
        }
        case urdf::Geometry::SPHERE:
          s.kind = CollisionShape::Kind::sphere, s.radius_m = static_cast<const urdf::Sphere*>(col->geometry.get())->radius;
          break;
        default:
          throw std::invalid_argument("URDF: link '" + s.link + "' has collision geometry other than a cylinder, box or sphere");
      }
      im.shapes.push_back(s);
    }
  };
  for (std::size_t f = 0; f < im.link_names.size(); ++f) {
    const auto link = model.getLink(im.link_names[f]);
    if (link) add_shapes(link, static_cast<int>(f), Eigen::Isometry3d::Identity(), false);
  }
  // The machine's body off the chain (the rig's carrier): links named carrier* fixed to base_link,
  // on base_link's frame (no joint moves them; they move with the base, robot.place_base). Boxes
  // only: a box's column in a scan is the machine's own (machine_points). Other links off the chain
  // (a scanner's mount, a mesh chassis) stay unread, as before.
  if (const auto base = model.getLink("base_link")) {
    for (const auto& joint : base->child_joints) {
      if (!joint || joint->type != urdf::Joint::FIXED || joint->child_link_name.rfind("carrier", 0) != 0) continue;
      if (std::find(im.link_names.begin(), im.link_names.end(), joint->child_link_name) != im.link_names.end()) continue;
      const auto child = model.getLink(joint->child_link_name);
      if (!child) continue;
      const std::size_t first = im.shapes.size();
      add_shapes(child, 0, to_isometry(joint->parent_to_joint_origin_transform), true);
      for (std::size_t k = first; k < im.shapes.size(); ++k) {
        if (im.shapes[k].kind != CollisionShape::Kind::box)
          throw std::invalid_argument("URDF: the carrier link '" + im.shapes[k].link + "' must be made of <box> collision shapes");
        // Its column in a scan runs along base_link's z (machine_points): upright boxes only.
        if (!(im.shapes[k].origin.linear().col(2).z() > 1.0 - 1e-9))
          throw std::invalid_argument("URDF: the carrier link '" + im.shapes[k].link +
                                      "' has a box turned off the vertical (only a turn about base_link's z is allowed)");
      }
    }
  }
  return robot;
}

int Robot::dof() const { return static_cast<int>(impl_->names.size()); }
const std::vector<std::string>& Robot::joint_names() const { return impl_->names; }
const std::vector<bool>& Robot::joint_is_prismatic() const { return impl_->prismatic; }
const Eigen::VectorXd& Robot::lower_limits() const { return impl_->lower; }
const Eigen::VectorXd& Robot::upper_limits() const { return impl_->upper; }
const Eigen::VectorXd& Robot::velocity_limits() const { return impl_->velocity; }
const Eigen::VectorXd& Robot::acceleration_limits() const { return impl_->acceleration; }
const Eigen::Isometry3d& Robot::base_pose() const { return impl_->base; }

Robot Robot::placed_at(const Eigen::Vector3d& base_position_m) const {
  if (!base_position_m.allFinite()) throw std::invalid_argument("robot.base_position_m contains NaN or inf");
  Robot r(*this);
  r.impl_->base.translation() = base_position_m;
  return r;
}
Robot Robot::carrier_turned(double yaw_rad) const {
  if (!std::isfinite(yaw_rad)) throw std::invalid_argument("carrier_turned: the angle is not finite");
  Robot r(*this);
  // From where the URDF puts it: turning a turned robot again sets the heading, never adds to it.
  const Eigen::Isometry3d turn(Eigen::AngleAxisd(yaw_rad - impl_->carrier_yaw_rad, Eigen::Vector3d::UnitZ()));
  for (auto& s : r.impl_->shapes)
    if (s.carrier) s.origin = turn * s.origin;
  r.impl_->carrier_yaw_rad = yaw_rad;
  return r;
}
const std::string& Robot::urdf_path() const { return impl_->path; }
Eigen::Vector3d Robot::shoulder_position() const { return impl_->base * impl_->shoulder_in_base; }
double Robot::max_reach_m() const { return impl_->max_reach_m; }

Eigen::Isometry3d Robot::fk(const Eigen::VectorXd& q) const {
  check_q(*this, q, "q");
  Kin kin(*impl_);
  Eigen::Isometry3d f = Eigen::Isometry3d::Identity();
  Eigen::Vector3d p;
  Eigen::Matrix3d R;
  kin.pose(q, p, R);
  f.linear() = R;
  f.translation() = p;
  return impl_->base * f;
}

namespace {
std::vector<Eigen::Isometry3d> compose_frames(const Robot::Impl& r, const Eigen::VectorXd& q, std::vector<JointAxis>* joints) {
  std::vector<Eigen::Isometry3d> out;
  out.reserve(r.link_names.size());
  out.push_back(r.base);
  if (joints) joints->clear();
  KDL::Frame f = KDL::Frame::Identity();
  int j = 0;
  for (std::size_t i = 0; i < r.chain.segments.size(); ++i) {
    const KDL::Joint& joint = r.chain.segments[i].getJoint();
    const bool moves = joint.getType() != KDL::Joint::None;
    if (moves && joints) {
      // As Kin::compose: the axis through the joint's origin, both in the parent's frame.
      const KDL::Vector a = f.M * joint.JointAxis(), o = f * joint.JointOrigin();
      JointAxis ja;
      ja.axis = r.base.linear() * Eigen::Vector3d(a.x(), a.y(), a.z()).normalized();
      ja.point_m = r.base * Eigen::Vector3d(o.x(), o.y(), o.z());
      ja.rotational = !r.prismatic[static_cast<std::size_t>(j)];  // URDF: revolute or prismatic, in q's order
      ja.first_frame = static_cast<int>(i) + 1;
      joints->push_back(ja);
    }
    const double qi = moves ? q[j++] : 0.0;
    f = f * joint_pose(joint, qi) * r.segment_tip[i];
    out.push_back(r.base * to_eigen(f));
  }
  return out;
}
}  // namespace

std::vector<Eigen::Isometry3d> Robot::link_frames(const Eigen::VectorXd& q) const {
  check_q(*this, q, "q");
  return compose_frames(*impl_, q, nullptr);
}

std::vector<Eigen::Isometry3d> Robot::link_frames(const Eigen::VectorXd& q, std::vector<JointAxis>& joints) const {
  check_q(*this, q, "q");
  return compose_frames(*impl_, q, &joints);
}

const std::vector<std::string>& Robot::link_names() const { return impl_->link_names; }
const std::vector<CollisionShape>& Robot::collision_shapes() const { return impl_->shapes; }

Eigen::MatrixXd Robot::jacobian(const Eigen::VectorXd& q) const {
  check_q(*this, q, "q");
  Kin kin(*impl_);
  Eigen::MatrixXd J = kin.jacobian(q);
  // Base is a pure translation here, but rotate anyway in case the frame ever gains a rotation.
  J.topRows(3) = impl_->base.linear() * J.topRows(3);
  J.bottomRows(3) = impl_->base.linear() * J.bottomRows(3);
  return J;
}

Eigen::VectorXd Robot::neutral() const { return impl_->neutral; }
Eigen::VectorXd Robot::stow() const { return impl_->stow; }

bool Robot::within_limits(const Eigen::VectorXd& q, double slack) const {
  if (q.size() != dof() || !q.allFinite()) return false;
  return ((q - impl_->lower).array() >= -slack).all() && ((impl_->upper - q).array() >= -slack).all();
}

}  // namespace shotcrete
