// End-to-end tests of `fluxgraph scale`: the real binary renders the
// quick-start job at 1 and 2 threads with tiny settings, and the test checks
// the printed table, the CSV rows, the PNG plot (matplotlib is a dependency, so
// a missing one fails the test) and the exit codes of bad input.
#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

using test::CommandResult;
using test::readText;
using test::runFluxgraph;
using test::sourcePath;
using test::writeText;

fs::path scratchDirectory() { return test::scratchDirectory("scale_cli"); }

std::string quickstartJob() { return (fs::path(FLUXGRAPH_SOURCE_DIR) / "data/jobs/quickstart.toml").string(); }

std::vector<std::string> tinyScale(std::vector<std::string> args) {
    for (const char* set : {"film.width=32", "film.height=32", "passes.pt.spp=2"}) {
        args.push_back("--set");
        args.push_back(set);
    }
    return args;
}

std::vector<std::string> splitLines(const std::string& text) {
    std::vector<std::string> lines;
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);) lines.push_back(line);
    return lines;
}

int countLines(const std::string& text) { return static_cast<int>(splitLines(text).size()); }

TEST(ScaleCli, QuickstartAtOneAndTwoThreadsWritesCsvAndPlotAndFindsIdenticalImages) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(
        dir, tinyScale({"scale", quickstartJob(), "--threads", "1,2", "--repeat", "1", "--out", "out", "--plot",
                        "scaling.png"}));
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_NE(r.out.find("images: bit-identical at 1, 2 threads"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("speed-up"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("wrote scaling.png"), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find("plot not drawn"), std::string::npos) << r.out;

    const std::vector<std::string> rows = splitLines(readText(dir / "out" / "scale.csv"));
    ASSERT_EQ(rows.size(), 5u) << readText(dir / "out" / "scale.csv");  // header, pt x2, pipeline x2
    EXPECT_EQ(rows[0], "pass,threads,median_s,min_s,max_s,speedup,efficiency,serial_fraction,oversubscribed");
    std::set<std::string> passThreads;
    for (std::size_t i = 1; i < rows.size(); ++i) {
        std::vector<std::string> fields;
        std::istringstream in(rows[i]);
        for (std::string field; std::getline(in, field, ',');) fields.push_back(field);
        ASSERT_EQ(fields.size(), 9u) << rows[i];
        passThreads.insert(fields[0] + "@" + fields[1]);
        EXPECT_GT(std::stod(fields[2]), 0.0) << rows[i];
        EXPECT_LE(std::stod(fields[3]), std::stod(fields[2])) << rows[i];  // min <= median <= max
        EXPECT_GE(std::stod(fields[4]), std::stod(fields[2])) << rows[i];
        if (fields[1] == "1") {
            EXPECT_EQ(std::stod(fields[5]), 1.0) << rows[i];
            EXPECT_EQ(std::stod(fields[6]), 1.0) << rows[i];
        }
        const double f = std::stod(fields[7]);
        EXPECT_GE(f, 0.0) << rows[i];
        EXPECT_LE(f, 1.0) << rows[i];
    }
    EXPECT_EQ(passThreads, (std::set<std::string>{"pt@1", "pt@2", "pipeline@1", "pipeline@2"}));

    const std::string png = readText(dir / "scaling.png");
    ASSERT_GE(png.size(), 8u) << "no plot: " << r.out;
    EXPECT_EQ(png.substr(0, 8), std::string("\x89PNG\r\n\x1a\n", 8));
}

TEST(ScaleCli, RunsOneThreadAsTheBaselineWhenNotAskedAndWritesTheCsvWhereTold) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(
        dir, tinyScale({"scale", quickstartJob(), "--threads", "2", "--repeat", "1", "--out", "out", "--csv", "t.csv"}));
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    EXPECT_NE(r.out.find("run anyway as the baseline"), std::string::npos) << r.out;
    const std::string csv = readText(dir / "t.csv");
    EXPECT_NE(csv.find("\npt,1,"), std::string::npos) << csv;
    EXPECT_NE(csv.find("\npipeline,2,"), std::string::npos) << csv;
    EXPECT_FALSE(fs::exists(dir / "out" / "scale.csv"));
}

TEST(ScaleCli, BadInputCostsOneLineAndExitCodeTwo) {
    const fs::path dir = scratchDirectory();
    const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
        {{"scale", quickstartJob(), "--threads", "1,,2"}, "--threads '1,,2'"},
        {{"scale", quickstartJob(), "--threads", "0,2"}, "--threads '0,2'"},
        {{"scale", quickstartJob(), "--threads", "1,-4"}, "--threads '1,-4'"},
        {{"scale", quickstartJob(), "--threads", "a"}, "--threads 'a'"},
        {{"scale", quickstartJob(), "--repeat", "0"}, "--repeat 0"},
        {{"scale", quickstartJob(), "--repeat", "-3"}, "--repeat -3"},
        {{"scale", (dir / "missing.toml").string(), "--threads", "1"}, "missing.toml"},
        {{"scale", quickstartJob(), "--threads", "1", "--set", "passes.pt.spp=banana"}, "passes.pt.spp"},
    };
    for (const auto& [args, expected] : cases) {
        const CommandResult r = runFluxgraph(dir, args);
        EXPECT_EQ(r.exitCode, 2) << args[3] << ": " << r.out << r.err;
        EXPECT_EQ(countLines(r.err), 1) << r.err;
        EXPECT_NE(r.err.find(expected), std::string::npos) << r.err;
        EXPECT_TRUE(r.out.empty()) << r.out;
    }
}

}  // namespace
}  // namespace fg
