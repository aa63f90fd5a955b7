// Replays every checked-in fuzz input (tests/fuzz/corpus/<target>/ and
// tests/fuzz/regressions/<target>/) through the entry points the fuzz targets
// call, in the normal build: no crash, and nothing but InputError escapes. A
// file named ok-* must be accepted and bad-* refused; other files (seeds, and
// inputs a fuzzer found) may be either.
#include "tests/fuzz/fuzz_entry.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <ostream>
#include <string>
#include <vector>

namespace fg::fuzz {

// Names the target in gtest's messages (instead of its bytes).
void PrintTo(const Target& target, std::ostream* out) { *out << target.name; }
void PrintTo(Verdict verdict, std::ostream* out) { *out << (verdict == Verdict::Accepted ? "accepted" : "refused"); }

}  // namespace fg::fuzz

namespace {

namespace fs = std::filesystem;

const fs::path kFuzzDir = fs::path(FLUXGRAPH_SOURCE_DIR) / "tests" / "fuzz";

std::vector<fs::path> filesIn(const fs::path& directory) {
    std::vector<fs::path> files;
    if (!fs::is_directory(directory)) return files;
    for (const fs::directory_entry& entry : fs::directory_iterator(directory))
        if (entry.is_regular_file()) files.push_back(entry.path());
    std::sort(files.begin(), files.end());
    return files;
}

std::vector<std::uint8_t> readBytes(const fs::path& file) {
    std::ifstream in(file, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Runs every file of `directory`; returns how many there were.
std::size_t replay(const fg::fuzz::Target& target, const fs::path& directory) {
    const std::vector<fs::path> files = filesIn(directory);
    for (const fs::path& file : files) {
        SCOPED_TRACE(file.string());
        const std::vector<std::uint8_t> bytes = readBytes(file);
        const std::string name = file.filename().string();
        try {
            const fg::fuzz::Verdict verdict = target.entry(bytes);
            if (name.starts_with("ok-")) {
                EXPECT_EQ(verdict, fg::fuzz::Verdict::Accepted) << name;
            } else if (name.starts_with("bad-")) {
                EXPECT_EQ(verdict, fg::fuzz::Verdict::Refused) << name;
            }
        } catch (const std::exception& e) {
            ADD_FAILURE() << name << ": not an input error: " << e.what();
        } catch (...) {
            ADD_FAILURE() << name << ": an exception that is not std::exception";
        }
    }
    return files.size();
}

class FuzzReplay : public ::testing::TestWithParam<fg::fuzz::Target> {};

TEST_P(FuzzReplay, CorpusIsAcceptedOrRefusedWithAnInputError) {
    EXPECT_GT(replay(GetParam(), kFuzzDir / "corpus" / std::string(GetParam().name)), 0u)
        << "no seed inputs for " << GetParam().name;
}

TEST_P(FuzzReplay, RegressionsAreAcceptedOrRefusedWithAnInputError) {
    EXPECT_GT(replay(GetParam(), kFuzzDir / "regressions" / std::string(GetParam().name)), 0u)
        << "no regression inputs for " << GetParam().name;
}

std::string targetName(const ::testing::TestParamInfo<fg::fuzz::Target>& target) {
    return std::string(target.param.name);
}

INSTANTIATE_TEST_SUITE_P(Targets, FuzzReplay, ::testing::ValuesIn(fg::fuzz::targets().begin(), fg::fuzz::targets().end()),
                         targetName);

}  // namespace
