#include "cloud_header.hpp"

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace shotcrete::detail {
namespace {

using u64 = std::uint64_t;
constexpr u64 kMaxCount = u64{1} << 40;  // beyond any scan; keeps every product below 2^63

[[noreturn]] void fail(const std::string& path, const std::string& what) {
  throw std::invalid_argument(path + ": " + what);
}

std::vector<std::string> tokens(const std::string& line) {
  std::istringstream ss(line);
  std::vector<std::string> out;
  std::string t;
  while (ss >> t) out.push_back(t);
  return out;
}

/// A whole number in [0, kMaxCount]; `what` names it in the message ("POINTS", "element vertex").
u64 count_of(const std::string& path, const std::string& what, const std::string& text) {
  const bool digits = !text.empty() && text.size() <= 15 && text.find_first_not_of("0123456789") == std::string::npos;
  if (!digits) fail(path, what + " = '" + printable(text) + "': expected a whole number >= 0");
  const u64 n = std::stoull(text);
  if (n > kMaxCount) fail(path, what + " = " + text + " is beyond any point cloud");
  return n;
}

u64 file_size(const std::string& path) { return static_cast<u64>(std::filesystem::file_size(path)); }

/// Non-blank lines from the stream's position on; fails at the first value that is not a number
/// (PCL would read it as 0) or line whose value count is not `values_per_line` (0: not checked).
/// Returns the line count.
u64 count_data_lines(std::istream& in, const std::string& path, std::size_t values_per_line, u64 header_lines) {
  u64 lines = 0, line_no = header_lines;
  std::string line;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    ++lines;
    const auto values = tokens(line);
    for (const auto& v : values) {
      char* end = nullptr;
      std::strtod(v.c_str(), &end);
      if (end != v.c_str() + v.size())
        fail(path, "line " + std::to_string(line_no) + ": '" + printable(v) + "' is not a number");
    }
    const std::size_t n = values.size();
    if (values_per_line != 0 && n != values_per_line)
      fail(path, "line " + std::to_string(line_no) + " has " + std::to_string(n) + " values, the header declares " +
                     std::to_string(values_per_line) + " per point");
  }
  return lines;
}

/// True when the `count` bytes from `offset` on are all zero: PCL 1.13's binary PCD writer pads
/// its files with zeros to the next 4 KiB page.
bool zero_padding(const std::string& path, u64 offset, u64 count) {
  if (count >= 4096) return false;
  std::ifstream in(path, std::ios::binary);
  in.seekg(static_cast<std::streamoff>(offset));
  std::vector<char> tail(static_cast<std::size_t>(count));
  return in.read(tail.data(), static_cast<std::streamsize>(count)) &&
         std::all_of(tail.begin(), tail.end(), [](char c) { return c == 0; });
}

/// The data of `available` bytes from `offset` must be the `expected` bytes the header declares,
/// plus less than one `record` or a zero padding.
void check_data_bytes(const std::string& path, u64 offset, u64 available, u64 expected, u64 record,
                      const std::string& what) {
  if (available < expected)
    fail(path, "the header declares " + what + " = " + std::to_string(expected) + " bytes of data but the file holds " +
                   std::to_string(available) + " (truncated, or the header overstates the count)");
  if (record > 0 && available - expected >= record && !zero_padding(path, offset + expected, available - expected))
    fail(path, "the header declares " + what + " = " + std::to_string(expected) + " bytes of data but the file holds " +
                   std::to_string(available) + " (the header understates the count)");
}

// ---- PCD ------------------------------------------------------------------------------------

struct PcdHeader {
  std::map<std::string, std::vector<std::string>> keys;
  std::string data;
  std::streamoff data_offset = 0;
  u64 lines = 0;
};

PcdHeader read_pcd_header(std::istream& in, const std::string& path) {
  PcdHeader h;
  std::string line;
  while (std::getline(in, line)) {
    ++h.lines;
    auto t = tokens(line);
    if (t.empty() || t[0][0] == '#') continue;
    const std::string key = t[0];
    t.erase(t.begin());
    if (key == "DATA") {
      if (t.size() != 1) fail(path, "DATA line without a single type (ascii, binary or binary_compressed)");
      h.data = t[0];
      h.data_offset = in.good() ? static_cast<std::streamoff>(in.tellg()) : -1;
      return h;
    }
    if (h.lines > 200) break;
    // PCL 1.13 stops its header parse at an unknown line and then reads from the wrong offset
    // (a segfault on binary_compressed data): only the keys of the format are accepted, once each.
    static const char* known[] = {"VERSION", "FIELDS", "COLUMNS", "SIZE", "TYPE", "COUNT",
                                  "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS"};
    if (std::none_of(std::begin(known), std::end(known), [&](const char* k) { return key == k; }))
      fail(path, h.keys.empty() ? "not a PCD file (it starts with '" + printable(line) + "')"
                                : "unknown PCD header line '" + printable(line) + "'");
    if (h.keys.count(key)) fail(path, "PCD header line " + key + " appears twice");
    h.keys[key == "COLUMNS" ? "FIELDS" : key] = t;
  }
  fail(path, "not a PCD file (no header with FIELDS, POINTS and DATA)");
}

/// Bytes per point from SIZE/TYPE/COUNT, checking each against FIELDS; also returns the value count.
u64 pcd_point_size(const PcdHeader& h, const std::string& path, std::size_t* values) {
  const auto& fields = h.keys.at("FIELDS");
  const auto& size = h.keys.count("SIZE") ? h.keys.at("SIZE") : std::vector<std::string>{};
  const auto& type = h.keys.count("TYPE") ? h.keys.at("TYPE") : std::vector<std::string>{};
  std::vector<std::string> count = h.keys.count("COUNT") ? h.keys.at("COUNT") : std::vector<std::string>(fields.size(), "1");
  if (size.size() != fields.size() || type.size() != fields.size() || count.size() != fields.size())
    fail(path, "FIELDS names " + std::to_string(fields.size()) + " fields but SIZE/TYPE/COUNT give " +
                   std::to_string(size.size()) + "/" + std::to_string(type.size()) + "/" + std::to_string(count.size()));
  u64 bytes = 0;
  *values = 0;
  for (std::size_t i = 0; i < fields.size(); ++i) {
    const std::string& s = size[i];
    const std::string& t = type[i];
    const bool ok_size = s == "1" || s == "2" || s == "4" || s == "8";
    const bool ok_type = t == "I" || t == "U" || (t == "F" && (s == "4" || s == "8"));
    if (!ok_size || !ok_type)
      fail(path, "field '" + printable(fields[i]) + "' has SIZE " + printable(s) + " TYPE " + printable(t) +
                     " (expected SIZE 1/2/4/8 and TYPE I/U, or F with SIZE 4/8)");
    const u64 c = count_of(path, "COUNT of '" + printable(fields[i]) + "'", count[i]);
    if (c == 0 || c > 1u << 16) fail(path, "COUNT of '" + printable(fields[i]) + "' must be in [1, 65536]");
    bytes += c * std::stoull(s);
    *values += static_cast<std::size_t>(c);
  }
  return bytes;
}

u64 pcd_points(const PcdHeader& h, const std::string& path) {
  auto one = [&](const char* key) -> std::string {
    const auto it = h.keys.find(key);
    if (it == h.keys.end()) return "";
    if (it->second.size() != 1) fail(path, std::string(key) + " must be one number");
    return it->second[0];
  };
  const std::string w = one("WIDTH"), hh = one("HEIGHT"), p = one("POINTS");
  if (w.empty() && p.empty()) fail(path, "the header has neither WIDTH nor POINTS");
  const u64 width = w.empty() ? 0 : count_of(path, "WIDTH", w);
  const u64 height = hh.empty() ? 1 : count_of(path, "HEIGHT", hh);
  if (!w.empty() && width * height > kMaxCount) fail(path, "WIDTH x HEIGHT is beyond any point cloud");
  const u64 points = p.empty() ? width * height : count_of(path, "POINTS", p);
  if (!w.empty() && width * height != points)
    fail(path, "the header disagrees with itself: WIDTH x HEIGHT = " + std::to_string(width) + " x " +
                   std::to_string(height) + " but POINTS = " + std::to_string(points));
  return points;
}

// ---- PLY ------------------------------------------------------------------------------------

struct PlyElement {
  std::string name;
  u64 count = 0;
  u64 fixed_bytes = 0;  // bytes of the scalar properties, plus the length field of each list
  bool has_list = false;
  std::vector<std::string> properties;
};

u64 ply_type_size(const std::string& t) {
  static const std::map<std::string, u64> sizes = {
      {"char", 1},  {"int8", 1},   {"uchar", 1},  {"uint8", 1},   {"short", 2},   {"int16", 2},   {"ushort", 2},
      {"uint16", 2}, {"int", 4},   {"int32", 4},  {"uint", 4},    {"uint32", 4},  {"float", 4},   {"float32", 4},
      {"double", 8}, {"float64", 8}};
  const auto it = sizes.find(t);
  return it == sizes.end() ? 0 : it->second;
}

void add_ply_property(const std::string& path, std::vector<PlyElement>& elements, const std::vector<std::string>& t) {
  if (elements.empty()) fail(path, "PLY property before any element");
  PlyElement& e = elements.back();
  const bool list = t.size() == 5 && t[1] == "list";
  if (!list && t.size() != 3) fail(path, "malformed PLY property line (" + std::to_string(t.size()) + " words)");
  const std::string& type = list ? t[2] : t[1];
  if (ply_type_size(type) == 0 || (list && ply_type_size(t[3]) == 0))
    fail(path, "PLY property '" + printable(t.back()) + "' has an unknown type '" + printable(list ? t[3] : type) + "'");
  e.fixed_bytes += ply_type_size(type);
  e.has_list = e.has_list || list;
  e.properties.push_back(t.back());
}

}  // namespace

void check_pcd_header(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  PcdHeader h = read_pcd_header(in, path);
  if (!h.keys.count("FIELDS")) fail(path, "not a PCD file (no FIELDS line)");
  std::size_t values = 0;
  const u64 point_size = pcd_point_size(h, path, &values);
  const u64 points = pcd_points(h, path);
  const u64 size = file_size(path);
  const u64 available = h.data_offset < 0 ? 0 : size - std::min(size, static_cast<u64>(h.data_offset));
  const std::string declared = "POINTS " + std::to_string(points) + " x " + std::to_string(point_size) + " bytes";
  if (h.data == "ascii") {
    if (points > available) fail(path, "POINTS " + std::to_string(points) + " cannot fit in " +
                                           std::to_string(available) + " bytes of ascii data");
    const u64 lines = count_data_lines(in, path, values, h.lines);
    if (lines != points)
      fail(path, "the header declares POINTS " + std::to_string(points) + " but the data has " +
                     std::to_string(lines) + " points (lines)");
  } else if (h.data == "binary") {
    check_data_bytes(path, size - available, available, points * point_size, point_size, declared);
  } else if (h.data == "binary_compressed") {
    std::uint32_t sizes[2] = {0, 0};
    if (available < 8 || !in.read(reinterpret_cast<char*>(sizes), 8))
      fail(path, "binary_compressed data without its 8-byte size block (truncated)");
    if (sizes[1] != points * point_size)
      fail(path, "the header declares " + declared + " = " + std::to_string(points * point_size) +
                     " bytes but the compressed block holds " + std::to_string(sizes[1]));
    if (sizes[0] > available - 8)
      fail(path, "the compressed block claims " + std::to_string(sizes[0]) + " bytes but the file holds " +
                     std::to_string(available - 8) + " (truncated)");
  } else {
    fail(path, "DATA " + printable(h.data) + ": expected ascii, binary or binary_compressed");
  }
}

void check_ply_header(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string line, format;
  std::vector<PlyElement> elements;
  u64 header_lines = 0;
  bool ended = false;
  while (!ended && header_lines < 10000 && std::getline(in, line)) {
    ++header_lines;
    const auto t = tokens(line);
    if (header_lines == 1 && (t.size() != 1 || t[0] != "ply")) fail(path, "not a PLY file (no 'ply' magic line)");
    if (t.empty() || t[0] == "ply" || t[0] == "comment" || t[0] == "obj_info") continue;
    if (t[0] == "format") {
      format = t.size() == 3 ? t[1] : "";
    } else if (t[0] == "element") {
      if (t.size() != 3) fail(path, "malformed PLY element line");
      elements.push_back(PlyElement{t[1], count_of(path, "element " + printable(t[1]), t[2]), 0, false, {}});
    } else if (t[0] == "property") {
      add_ply_property(path, elements, t);
    } else if (t[0] == "end_header") {
      ended = true;
    } else {
      fail(path, "unknown PLY header line '" + printable(line) + "'");
    }
  }
  if (!ended) fail(path, "PLY header without end_header");
  if (format != "ascii" && format != "binary_little_endian" && format != "binary_big_endian")
    fail(path, "PLY format '" + printable(format) + "': expected ascii, binary_little_endian or binary_big_endian");
  const PlyElement* vertex = nullptr;
  for (const auto& e : elements)
    if (e.name == "vertex") vertex = &e;
  if (!vertex) fail(path, "the PLY file has no vertex element");
  for (const char* axis : {"x", "y", "z"})
    if (std::find(vertex->properties.begin(), vertex->properties.end(), axis) == vertex->properties.end())
      fail(path, std::string("the PLY vertex element has no '") + axis + "' property");
  const std::streamoff offset = in.good() ? static_cast<std::streamoff>(in.tellg()) : -1;
  const u64 size = file_size(path);
  const u64 available = offset < 0 ? 0 : size - std::min(size, static_cast<u64>(offset));
  u64 total = 0, bytes = 0;
  bool lists = false;
  for (const auto& e : elements) {
    total += e.count;
    bytes += e.count * e.fixed_bytes;
    lists = lists || e.has_list;
  }
  const std::string declared = "element vertex " + std::to_string(vertex->count);
  if (format == "ascii") {
    if (total > available) fail(path, declared + " cannot fit in " + std::to_string(available) + " bytes of ascii data");
    const u64 rows = count_data_lines(in, path, 0, header_lines);
    if (rows != total)
      fail(path, "the header declares " + std::to_string(total) + " element rows (" + declared +
                     ") but the data has " + std::to_string(rows) + " lines");
  } else if (lists) {
    if (available < bytes) fail(path, "the header declares at least " + std::to_string(bytes) + " bytes of data (" +
                                          declared + ") but the file holds " + std::to_string(available));
  } else {
    check_data_bytes(path, size - available, available, bytes, vertex->fixed_bytes, declared);
  }
}

}  // namespace shotcrete::detail
