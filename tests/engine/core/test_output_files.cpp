// Checked writes and all-or-nothing commits of output files: a full disk is
// an InputError naming the final path, never a truncated file, and a failed
// set of outputs leaves neither files nor the directories made for them.
#include "engine/core/output_files.h"

#include "engine/core/error.h"

#include "tests/support/cli_helpers.h"
#include "tests/support/small_filesystem.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

std::vector<std::string> entriesBelow(const fs::path& dir) {
    std::vector<std::string> names;
    for (const auto& entry : fs::recursive_directory_iterator(dir))
        names.push_back(fs::relative(entry.path(), dir).string());
    std::sort(names.begin(), names.end());
    return names;
}

TEST(OutputFiles, WritesTheBytesToTheTemporary) {
    const fs::path dir = test::scratchDirectory("output_files");
    const std::string final = (dir / "a.txt").string();
    const std::string temporary = temporaryPathFor(final);
    writeFileChecked(final, temporary, std::string(200000, 'x') + "end");
    EXPECT_EQ(test::readText(temporary), std::string(200000, 'x') + "end");
    EXPECT_FALSE(fs::exists(final));
}

TEST(OutputFiles, AFullDiskIsAnInputErrorNamingTheFinalPathAndLeavesNoTemporary) {
    const fs::path dir = test::scratchDirectory("output_files") / "small";
    test::SmallFilesystem small(dir, 64 * 1024);
    FG_SKIP_UNLESS_MOUNTED(small);
    const std::string final = (dir / "big.bin").string();
    for (const bool streamed : {false, true}) {
        try {
            const std::string bytes(256 * 1024, 'x');
            if (streamed)
                writeFileChecked(final, temporaryPathFor(final), [&](std::ostream& out) {
                    for (int i = 0; i < 256; ++i) out.write(bytes.data(), 1024);
                });
            else
                writeFileChecked(final, temporaryPathFor(final), bytes);
            ADD_FAILURE() << "a 256 KiB write to a 64 KiB filesystem succeeded";
        } catch (const InputError& e) {
            EXPECT_EQ(std::string(e.what()), final + ": cannot write: No space left on device");
        }
        EXPECT_TRUE(entriesBelow(dir).empty());
    }
}

TEST(OutputFiles, ACommitRenamesEveryStagedFile) {
    const fs::path dir = test::scratchDirectory("output_files");
    const fs::path out = dir / "new" / "out";
    OutputCommit outputs;
    outputs.createDirectories(out.string());
    for (const char* name : {"a.exr", "b.png"})
        writeFileChecked((out / name).string(), outputs.stage((out / name).string()), name);
    outputs.commit();
    EXPECT_EQ(entriesBelow(dir), (std::vector<std::string>{"new", "new/out", "new/out/a.exr", "new/out/b.png"}));
    EXPECT_EQ(test::readText(out / "b.png"), "b.png");
}

TEST(OutputFiles, AFinalNameTakenByADirectoryCommitsNothing) {
    const fs::path dir = test::scratchDirectory("output_files");
    fs::create_directories(dir / "b.png");
    {
        OutputCommit outputs;
        for (const char* name : {"a.exr", "b.png", "c.json"})
            writeFileChecked((dir / name).string(), outputs.stage((dir / name).string()), name);
        try {
            outputs.commit();
            ADD_FAILURE() << "committed onto a directory";
        } catch (const InputError& e) {
            EXPECT_EQ(std::string(e.what()), (dir / "b.png").string() + ": cannot write: is a directory");
        }
    }
    EXPECT_EQ(entriesBelow(dir), std::vector<std::string>{"b.png"});
}

TEST(OutputFiles, AnUncommittedSetRemovesItsTemporariesAndTheDirectoriesItMade) {
    const fs::path dir = test::scratchDirectory("output_files");
    fs::create_directories(dir / "kept");
    {
        OutputCommit outputs;
        outputs.createDirectories((dir / "kept" / "made" / "deeper").string());
        const std::string final = (dir / "kept" / "made" / "deeper" / "a.exr").string();
        writeFileChecked(final, outputs.stage(final), "half a render");
    }
    EXPECT_EQ(entriesBelow(dir), std::vector<std::string>{"kept"});
}

}  // namespace
}  // namespace fg
