#include "shotcrete/io/text.hpp"

namespace shotcrete {

std::string printable(const std::string& text, std::size_t max) {
  std::string out;
  for (unsigned char c : text.substr(0, max)) out += (c >= 32 && c < 127) ? static_cast<char>(c) : '?';
  return text.size() > max ? out + "..." : out;
}

}  // namespace shotcrete
