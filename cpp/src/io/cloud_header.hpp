#pragma once
// Header checks of PCD and PLY files before PCL reads them (docs/architecture.md §3, "Readers"):
// a header that disagrees with the data (point counts, sizes, types) is an error naming the file
// and the mismatch, and every count is checked against the file size before anything is allocated.
#include <string>

#include "shotcrete/io/text.hpp"

namespace shotcrete::detail {

/// Throws std::invalid_argument "<path>: <what disagrees>" unless the PCD header is well formed
/// and its POINTS (= WIDTH x HEIGHT) match the data: the number of lines (ascii), the byte count
/// (binary) or the compressed block's sizes (binary_compressed).
void check_pcd_header(const std::string& path);

/// Throws std::invalid_argument unless the PLY header is well formed, has a vertex element with
/// x, y and z, and its element counts match the data: one line per element (ascii), the exact byte
/// count (binary, elements of fixed size) or at least the smallest possible one (list properties).
void check_ply_header(const std::string& path);

using shotcrete::printable;

}  // namespace shotcrete::detail
