// Errors caused by the user's input (job files, scenes, parameters, paths).
// The CLI turns an InputError into one line "file:line: message" and exit code 2;
// anything else escaping is a bug in fluxgraph.
#pragma once

#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

namespace fg {

class InputError : public std::runtime_error {
public:
    InputError(std::string file, int line, const std::string& message)
        : std::runtime_error(format(file, line, message)), file_(std::move(file)), line_(line) {}
    explicit InputError(const std::string& message) : std::runtime_error(message), line_(0) {}
    // Several independent problems of one input, each a complete message
    // ("file:line: ..."), so that a user sees them all at once; what() holds
    // them one per line, and the CLI prints one line each.
    explicit InputError(std::vector<std::string> problems)
        : std::runtime_error(joinLines(problems)), line_(0), problems_(std::move(problems)) {}

    const std::string& file() const { return file_; }
    int line() const { return line_; }
    // Empty unless the error was made from several problems.
    const std::vector<std::string>& problems() const { return problems_; }

private:
    static std::string joinLines(const std::vector<std::string>& lines) {
        std::string text;
        for (const std::string& line : lines) text += (text.empty() ? "" : "\n") + line;
        return text;
    }
    static std::string format(const std::string& file, int line, const std::string& message) {
        if (file.empty()) return message;
        return line > 0 ? file + ":" + std::to_string(line) + ": " + message : file + ": " + message;
    }
    std::string file_;
    int line_;
    std::vector<std::string> problems_;
};

// `message` made safe to print as one terminal line: control characters
// (newlines, tabs and the C1 range included) and bytes that are not part of
// valid UTF-8 become \xNN, one per byte; valid UTF-8 such as "é" or "×" is
// kept as is. Input files can hold any bytes, and messages quote them.
std::string printableMessage(std::string_view message);

}  // namespace fg
