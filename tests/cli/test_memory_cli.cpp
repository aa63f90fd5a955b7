// The program's resident memory at start-up and for a small render: OpenImageIO
// and the 260 libraries it links once took 135 MiB before any work, so
// writing and reading EXR and PNG must not load it.
#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/wait.h>

#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

#if defined(__SANITIZE_ADDRESS__)
#define FG_UNDER_ADDRESS_SANITIZER 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define FG_UNDER_ADDRESS_SANITIZER 1
#endif
#endif

// Peak resident set of one run, in bytes (Linux reports ru_maxrss in KiB).
long long peakResidentBytes(const fs::path& dir, const std::vector<std::string>& args) {
    const test::RunningFluxgraph process = test::startFluxgraph(dir, args);
    int status = 0;
    rusage usage{};
    EXPECT_EQ(wait4(process.pid, &status, 0, &usage), process.pid);
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "status " << status;
    return static_cast<long long>(usage.ru_maxrss) * 1024;
}

constexpr long long kMiB = 1024 * 1024;

TEST(MemoryCli, StartUpAndASmallRenderWithoutOpenImageIoStayUnderTheTargetOf64MiB) {
#ifdef FG_UNDER_ADDRESS_SANITIZER
    GTEST_SKIP() << "AddressSanitizer's shadow memory is counted as resident";
#endif
    const fs::path dir = test::scratchDirectory("memory_cli");
    EXPECT_LT(peakResidentBytes(dir, {"--help"}), 64 * kMiB);
    // Writes an EXR and a PNG and reads nothing else: the render needs no other format.
    EXPECT_LT(peakResidentBytes(dir, {"render", test::sourcePath("data/jobs/quickstart.toml"), "--out", "out", "-q",
                                      "--set", "passes.pt.spp=1", "--set", "film.width=32", "--set",
                                      "film.height=32"}),
              64 * kMiB);
    EXPECT_TRUE(fs::exists(dir / "out" / "quickstart.exr"));
    EXPECT_TRUE(fs::exists(dir / "out" / "quickstart.png"));
}

}  // namespace
}  // namespace fg
