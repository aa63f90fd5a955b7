// Reading the text files a user names (job files, batch plans, TOML and XML
// scenes) with one contract: a missing, unreadable or non-regular file, a path
// the system cannot take (a component over 255 bytes), or a file over the size
// bound is an InputError naming the path, never a filesystem exception and
// never a read that runs until memory is exhausted (/dev/zero, a FIFO).
#pragma once

#include <cstdint>
#include <string>

namespace fg {

// Text inputs are hand-written or generated descriptions, far below this.
inline constexpr std::uintmax_t kMaxTextInputBytes = 64ull * 1024 * 1024;

// The whole file at `path`; `what` names it in messages ("job file", "scene file").
std::string readTextInput(const std::string& path, const std::string& what);

}  // namespace fg
