#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <sys/wait.h>

#include <cstdlib>
#include <fstream>
#include <sstream>

namespace fg::test {

namespace fs = std::filesystem;

namespace {

std::string shellQuote(const std::string& word) {
    std::string quoted = "'";
    for (char c : word) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
    return quoted + "'";
}

}  // namespace

std::string readText(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    std::stringstream buffer;
    buffer << in.rdbuf();
    return buffer.str();
}

void writeText(const fs::path& path, const std::string& text) {
    if (path.has_parent_path()) fs::create_directories(path.parent_path());
    std::ofstream out(path, std::ios::binary);
    out << text;
    ASSERT_TRUE(out.good()) << path;
}

fs::path scratchDirectory(const std::string& group) {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    const fs::path dir = fs::path(FLUXGRAPH_TEST_TMP) / group / info->name();
    fs::remove_all(dir);
    fs::create_directories(dir);
    return dir;
}

CommandResult runFluxgraph(const fs::path& dir, const std::vector<std::string>& args) {
    const fs::path logs = dir / "logs";
    fs::create_directories(logs);
    std::string command = "cd " + shellQuote(dir.string()) + " && " + shellQuote(FLUXGRAPH_BINARY);
    for (const std::string& a : args) {
        command += ' ';  // appended separately: GCC 12 warns (-Wrestrict, falsely) on " " + string here
        command += shellQuote(a);
    }
    command += " </dev/null >" + shellQuote((logs / "stdout").string()) + " 2>" + shellQuote((logs / "stderr").string());
    const int status = std::system(command.c_str());
    CommandResult result;
    if (status != -1 && WIFEXITED(status)) result.exitCode = WEXITSTATUS(status);
    else if (status != -1 && WIFSIGNALED(status)) result.exitCode = 128 + WTERMSIG(status);
    result.out = readText(logs / "stdout");
    result.err = readText(logs / "stderr");
    return result;
}

std::string sourcePath(const std::string& relative) { return (fs::path(FLUXGRAPH_SOURCE_DIR) / relative).string(); }

}  // namespace fg::test
