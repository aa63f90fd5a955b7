// End-to-end tests of `fluxgraph replay`: the real binary replays one pass of a
// small job, prints a row per repetition and the median, says the outputs
// were identical, round-trips its inputs through --save-inputs / --inputs and
// writes a trace; bad requests cost one stderr line and exit code 2.
#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
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

fs::path scratchDirectory() { return test::scratchDirectory("cli-replay"); }

std::vector<std::string> replayGather(std::vector<std::string> extra) {
    std::vector<std::string> args = {"replay", sourcePath("data/jobs/cornell-spm.toml"), "--pass", "gather",
                                     "--set", "film.width=24", "--set", "film.height=24",
                                     "--set", "passes.eye.spp=1", "--set", "passes.photon.photons=3000"};
    args.insert(args.end(), extra.begin(), extra.end());
    return args;
}

void expectInputError(const CommandResult& r) {
    EXPECT_EQ(r.exitCode, 2) << "stderr: " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "stderr: " << r.err;
    EXPECT_EQ(r.err.find("internal error"), std::string::npos) << "stderr: " << r.err;
}

TEST(ReplayCli, PrintsRepetitionsMedianAndIdenticalOutputs) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(dir, replayGather({"--repeat", "3", "--threads", "2"}));
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("replay gather (pass gather), 3 repetitions, 2 threads"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("inputs made by 4 passes"), std::string::npos) << r.out;
    for (const char* row : {"\n1 ", "\n2 ", "\n3 ", "\nmedian "}) EXPECT_NE(r.out.find(row), std::string::npos) << row;
    EXPECT_EQ(r.out.find("\n4 "), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("outputs identical in every repetition: caustic (Film), global (Film)"), std::string::npos)
        << r.out;
}

TEST(ReplayCli, SaveInputsThenReplayFromThem) {
    const fs::path dir = scratchDirectory();
    const CommandResult saved = runFluxgraph(dir, replayGather({"--repeat", "1", "--save-inputs", "inputs"}));
    ASSERT_EQ(saved.exitCode, 0) << saved.err;
    EXPECT_TRUE(fs::exists(dir / "inputs" / "global_index.fgbuf"));
    EXPECT_NE(saved.out.find("wrote inputs/eye_vertices.fgbuf"), std::string::npos) << saved.out;
    const CommandResult loaded =
        runFluxgraph(dir, replayGather({"--repeat", "2", "--inputs", "inputs", "--profile", "trace.json"}));
    ASSERT_EQ(loaded.exitCode, 0) << loaded.err;
    EXPECT_NE(loaded.out.find("inputs loaded from files"), std::string::npos) << loaded.out;
    EXPECT_NE(readText(dir / "trace.json").find("\"gather #2\""), std::string::npos);
}

TEST(ReplayCli, UnknownPassListsInstances) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(dir, {"replay", sourcePath("data/jobs/cornell-spm.toml"), "--pass", "nope"});
    expectInputError(r);
    EXPECT_NE(r.err.find("instances: eye, photon"), std::string::npos) << r.err;
}

TEST(ReplayCli, RepeatBelowOneIsAnInputError) {
    const fs::path dir = scratchDirectory();
    expectInputError(runFluxgraph(dir, replayGather({"--repeat", "0"})));
}

TEST(ReplayCli, MissingInputFilesAreAnInputError) {
    const fs::path dir = scratchDirectory();
    const CommandResult r = runFluxgraph(dir, replayGather({"--inputs", "missing"}));
    expectInputError(r);
    EXPECT_NE(r.err.find("missing/"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace fg
