#include "engine/core/text_input.h"

#include "engine/core/error.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <system_error>

namespace fg {

std::string readTextInput(const std::string& path, const std::string& what) {
    namespace fs = std::filesystem;
    std::error_code ec;
    const fs::file_status status = fs::status(path, ec);
    if (status.type() == fs::file_type::not_found) throw InputError(path + ": cannot open " + what + " (not found)");
    if (ec) throw InputError(path + ": cannot open " + what + " (" + ec.message() + ")");
    if (status.type() != fs::file_type::regular) throw InputError(path + ": cannot open " + what + " (not a regular file)");
    const std::uintmax_t size = fs::file_size(path, ec);
    if (ec) throw InputError(path + ": cannot open " + what + " (" + ec.message() + ")");
    const auto tooLarge = [&] {
        return InputError(path + ": " + what + " is larger than " + std::to_string(kMaxTextInputBytes >> 20) + " MiB");
    };
    if (size > kMaxTextInputBytes) throw tooLarge();

    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path + ": cannot open " + what);
    // The file may have grown since its size was read: read at most one byte past the bound.
    std::string text(static_cast<std::size_t>(size) + 1, '\0');
    std::size_t length = 0;
    while (in && length < text.size()) {
        in.read(text.data() + length, static_cast<std::streamsize>(text.size() - length));
        length += static_cast<std::size_t>(in.gcount());
        if (length == text.size() && length <= kMaxTextInputBytes) text.resize(std::min<std::size_t>(2 * length, kMaxTextInputBytes + 1));
    }
    if (in.bad()) throw InputError(path + ": cannot read " + what);
    if (length > kMaxTextInputBytes) throw tooLarge();
    text.resize(length);
    return text;
}

}  // namespace fg
