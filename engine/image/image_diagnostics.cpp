#include "engine/image/image_diagnostics.h"

#include <unistd.h>

#include <algorithm>
#include <iostream>
#include <sstream>
#include <vector>

namespace fg {

namespace {

std::mutex& stderrMutex() {
    static std::mutex mutex;
    return mutex;
}

// A truncated or hostile file could make a library print a great deal; the
// message keeps to a line a person can read.
constexpr std::size_t kMaxCapturedBytes = 64 * 1024;
constexpr std::size_t kMaxFailureBytes = 1000;

std::string trimmed(const std::string& line) {
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos) return {};
    return line.substr(first, line.find_last_not_of(" \t\r") - first + 1);
}

}  // namespace

CapturedStderr::CapturedStderr() : lock_(stderrMutex()) {
    std::cerr.flush();
    std::fflush(stderr);
    file_ = std::tmpfile();
    if (!file_) return;
    savedStderr_ = dup(STDERR_FILENO);
    if (savedStderr_ < 0 || dup2(fileno(file_), STDERR_FILENO) < 0) {
        if (savedStderr_ >= 0) close(savedStderr_);
        savedStderr_ = -1;
        std::fclose(file_);
        file_ = nullptr;
    }
}

CapturedStderr::~CapturedStderr() {
    const std::string text = take();
    if (!text.empty()) {
        std::fwrite(text.data(), 1, text.size(), stderr);
        std::fflush(stderr);
    }
}

std::string CapturedStderr::take() {
    if (!file_) return {};
    std::cerr.flush();
    std::fflush(stderr);
    dup2(savedStderr_, STDERR_FILENO);
    close(savedStderr_);
    savedStderr_ = -1;
    std::string text;
    std::rewind(file_);
    char buffer[4096];
    std::size_t n = 0;
    while (text.size() < kMaxCapturedBytes && (n = std::fread(buffer, 1, sizeof buffer, file_)) > 0)
        text.append(buffer, n);
    std::fclose(file_);
    file_ = nullptr;
    return text;
}

std::string imageReadFailure(const std::string& reportedError, CapturedStderr& printed) {
    std::vector<std::string> lines;
    std::istringstream all(reportedError + "\n" + printed.take());
    for (std::string line; std::getline(all, line);)
        if (std::string t = trimmed(line); !t.empty()) lines.push_back(std::move(t));
    // OIIO often repeats libpng's words with a prefix ("Read error: x" then "PNG read error: IDAT: Read error: x").
    std::vector<std::string> kept;
    for (std::size_t i = 0; i < lines.size(); ++i) {
        const bool repeated = std::any_of(lines.begin(), lines.end(), [&](const std::string& other) {
            return &other != &lines[i] && other.find(lines[i]) != std::string::npos &&
                   (other != lines[i] || &other < &lines[i]);
        });
        if (!repeated) kept.push_back(lines[i]);
    }
    std::string joined;
    for (const std::string& line : kept) joined += (joined.empty() ? "" : "; ") + line;
    if (joined.empty()) return "unknown error";
    if (joined.size() > kMaxFailureBytes) joined = joined.substr(0, kMaxFailureBytes) + "...";
    return joined;
}

}  // namespace fg
