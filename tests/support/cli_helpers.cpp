#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <fcntl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <thread>

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
    const fs::path dir = fs::path(FLUXGRAPH_TEST_TMP) / group / (std::string(info->test_suite_name()) + "." + info->name());
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

RunningFluxgraph startFluxgraph(const fs::path& dir, const std::vector<std::string>& args, const StartOptions& options) {
    const fs::path logs = dir / "logs";
    fs::create_directories(logs);
    // Everything the child needs is made before fork: after it, a
    // multithreaded parent's child may only make async-signal-safe calls.
    std::vector<std::string> words = {FLUXGRAPH_BINARY};
    words.insert(words.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (std::string& w : words) argv.push_back(w.data());
    argv.push_back(nullptr);
    std::vector<std::string> environment;
    for (char** e = environ; *e; ++e) environment.emplace_back(*e);
    for (const auto& [name, value] : options.environment) environment.push_back(name + "=" + value);
    std::vector<char*> envp;
    for (std::string& e : environment) envp.push_back(e.data());
    envp.push_back(nullptr);
    const std::string directory = dir.string(), out = (logs / "stdout").string(), err = (logs / "stderr").string();
    ::unlink(err.c_str());
    const pid_t pid = ::fork();
    if (pid == 0) {
        const int in = ::open("/dev/null", O_RDONLY);
        const int outFd = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
        const int errFd = ::open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
        if (in < 0 || outFd < 0 || errFd < 0 || ::dup2(in, 0) < 0 || ::dup2(outFd, 1) < 0 || ::dup2(errFd, 2) < 0 ||
            ::chdir(directory.c_str()) != 0)
            ::_exit(127);
        if (options.addressSpaceLimit > 0) {
            const rlimit limit{static_cast<rlim_t>(options.addressSpaceLimit), static_cast<rlim_t>(options.addressSpaceLimit)};
            if (::setrlimit(RLIMIT_AS, &limit) != 0) ::_exit(127);
        }
        ::execve(argv[0], argv.data(), envp.data());
        ::_exit(127);
    }
    EXPECT_GT(pid, 0) << "fork failed";
    return {pid, dir};
}

bool waitForStderr(const RunningFluxgraph& process, const std::string& text, double seconds) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < deadline) {
        if (readText(process.dir / "logs" / "stderr").find(text) != std::string::npos) return true;
        siginfo_t info{};
        if (::waitid(P_PID, static_cast<id_t>(process.pid), &info, WEXITED | WNOHANG | WNOWAIT) == 0 && info.si_pid != 0)
            return false;
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return false;
}

CommandResult finishFluxgraph(const RunningFluxgraph& process) {
    int status = 0;
    CommandResult result;
    if (::waitpid(process.pid, &status, 0) == process.pid) {
        if (WIFEXITED(status)) result.exitCode = WEXITSTATUS(status);
        else if (WIFSIGNALED(status)) result.exitCode = 128 + WTERMSIG(status);
    }
    result.out = readText(process.dir / "logs" / "stdout");
    result.err = readText(process.dir / "logs" / "stderr");
    return result;
}

CommandResult runFluxgraphWith(const fs::path& dir, const std::vector<std::string>& args, const StartOptions& options) {
    return finishFluxgraph(startFluxgraph(dir, args, options));
}

std::string sourcePath(const std::string& relative) { return (fs::path(FLUXGRAPH_SOURCE_DIR) / relative).string(); }

}  // namespace fg::test
