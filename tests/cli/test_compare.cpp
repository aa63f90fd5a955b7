// End-to-end tests of `fluxgraph compare`: the real binary on images written
// here. Output is one "name value" line per metric, the values those of
// compareImages; every bad input costs exit code 2 and exactly one stderr line
// with nothing on stdout; the heatmap is written atomically.
#include "engine/image/image_compare.h"

#include "tests/support/cli_helpers.h"

#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
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

fs::path scratchDirectory() { return test::scratchDirectory("cli_compare"); }

// Runs `fluxgraph compare ARGS...` in `dir`; output captured in dir/logs.
CommandResult runCompare(const fs::path& dir, std::vector<std::string> args) {
    args.insert(args.begin(), "compare");
    return runFluxgraph(dir, args);
}

void expectInputError(const CommandResult& r) {
    EXPECT_EQ(r.exitCode, 2) << "stderr: " << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "stderr: " << r.err;
    EXPECT_TRUE(!r.err.empty() && r.err.back() == '\n') << "stderr: " << r.err;
    EXPECT_TRUE(r.out.empty()) << "stdout: " << r.out;
}

// Parses "name value" lines, in order.
std::vector<std::pair<std::string, double>> parseLines(const std::string& text) {
    std::vector<std::pair<std::string, double>> lines;
    std::istringstream in(text);
    std::string line;
    while (std::getline(in, line)) {
        std::istringstream words(line);
        std::string name, value, rest;
        words >> name >> value;
        EXPECT_FALSE(words >> rest) << "extra text on line: " << line;
        lines.emplace_back(name, std::strtod(value.c_str(), nullptr));
    }
    return lines;
}

ImageChannels texturedImage(int width, int height, float offset) {
    ImageChannels image;
    image.width = width;
    image.height = height;
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x)
            image.rgb.emplace_back(0.1f + 0.05f * static_cast<float>((x * 7 + y * 3) % 11) + offset,
                                   0.02f * static_cast<float>(y) + offset, 3.0f * static_cast<float>((x + y) % 2) + offset);
    return image;
}

std::string writeImage(const fs::path& dir, const std::string& name, const ImageChannels& image) {
    const fs::path path = dir / name;
    writeExr(path.string(), image, {});
    return path.string();
}

TEST(CliCompare, IdenticalImagesPrintEveryMetricInOrder) {
    const fs::path dir = scratchDirectory();
    const std::string a = writeImage(dir, "a.exr", texturedImage(16, 12, 0.0f));
    const CommandResult r = runCompare(dir, {a, a});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(r.out, "rmse 0\nrelmse 0\nmae 0\nssim 1\npsnr inf\nworst_relse 0\n");
    EXPECT_EQ(r.err, "");
}

TEST(CliCompare, PrintsTheLibraryValuesAndMetricSelectsOneLine) {
    const fs::path dir = scratchDirectory();
    const ImageChannels reference = texturedImage(20, 14, 0.0f);
    const ImageChannels test = texturedImage(20, 14, 0.125f);
    const std::string refPath = writeImage(dir, "ref.exr", reference);
    const std::string testPath = writeImage(dir, "test.exr", test);
    const ImageMetrics expected = compareImages(test, reference);
    const std::map<std::string, double> want = {{"rmse", expected.rmse},
                                                {"relmse", expected.relmse},
                                                {"mae", expected.mae},
                                                {"ssim", expected.ssim},
                                                {"psnr", expected.psnr},
                                                {"worst_relse", expected.worstRelse}};

    const CommandResult all = runCompare(dir, {testPath, refPath, "--metric", "all"});
    ASSERT_EQ(all.exitCode, 0) << all.err;
    const auto lines = parseLines(all.out);
    ASSERT_EQ(lines.size(), 6u) << all.out;
    const char* order[] = {"rmse", "relmse", "mae", "ssim", "psnr", "worst_relse"};
    for (std::size_t i = 0; i < lines.size(); ++i) {
        EXPECT_EQ(lines[i].first, order[i]);
        EXPECT_NEAR(lines[i].second, want.at(order[i]), 1e-9 * std::abs(want.at(order[i])));
    }
    EXPECT_NEAR(want.at("rmse"), 0.125, 1e-7);  // the offset, exactly representable

    for (const auto& [name, value] : want) {
        const CommandResult one = runCompare(dir, {testPath, refPath, "--metric", name});
        ASSERT_EQ(one.exitCode, 0) << one.err;
        const auto single = parseLines(one.out);
        ASSERT_EQ(single.size(), 1u) << one.out;
        EXPECT_EQ(single[0].first, name);
        EXPECT_NEAR(single[0].second, value, 1e-9 * std::abs(value));
    }
}

TEST(CliCompare, CropComparesOnlyTheRectangle) {
    const fs::path dir = scratchDirectory();
    const ImageChannels reference = texturedImage(24, 20, 0.0f);
    ImageChannels test = reference;
    // Rows 0..4 differ; the crop starts at row 5, counted from the top.
    for (std::size_t i = 0; i < 5u * 24u; ++i) test.rgb[i] += Rgb(1.0f);
    const std::string refPath = writeImage(dir, "ref.exr", reference);
    const std::string testPath = writeImage(dir, "test.exr", test);
    CommandResult r = runCompare(dir, {testPath, refPath, "--crop", "3,5,12,15", "--metric", "rmse"});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(r.out, "rmse 0\n");
    r = runCompare(dir, {testPath, refPath, "--crop", "3,4,12,15", "--metric", "mae"});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    const auto lines = parseLines(r.out);
    ASSERT_EQ(lines.size(), 1u);
    EXPECT_NEAR(lines[0].second, 12.0 / (12.0 * 15.0), 1e-7);  // one row of 12 pixels off by 1
}

TEST(CliCompare, BadInputsExitTwoWithOneLine) {
    const fs::path dir = scratchDirectory();
    const std::string a = writeImage(dir, "a.exr", texturedImage(16, 12, 0.0f));
    const std::string wide = writeImage(dir, "wide.exr", texturedImage(17, 12, 0.0f));
    const std::string tiny = writeImage(dir, "tiny.exr", texturedImage(8, 8, 0.0f));
    {
        std::ofstream garbage(dir / "garbage.exr", std::ios::binary);
        garbage << "not an image\nsecond line\n";
    }
    const std::vector<std::vector<std::string>> cases = {
        {a, wide},
        {wide, a},
        {a, (dir / "missing.exr").string()},
        {(dir / "garbage.exr").string(), a},
        {a, a, "--crop", "10,0,7,12"},
        {a, a, "--crop", "0,5,16,8"},
        {a, a, "--crop", "-1,0,4,4"},
        {a, a, "--crop", "0,0,0,4"},
        {a, a, "--crop", "1,2,3"},
        {a, a, "--crop", "1,2,3,4,5"},
        {a, a, "--crop", "1,2,x,4"},
        {a, a, "--metric", "psnr2"},
        {tiny, tiny, "--metric", "ssim"},
        {a, a, "--heatmap", (dir / "no-such-dir" / "heat.png").string()},
        {a},
    };
    for (const auto& args : cases) {
        SCOPED_TRACE(::testing::PrintToString(args));
        expectInputError(runCompare(dir, args));
    }
    EXPECT_FALSE(fs::exists(dir / "no-such-dir"));
    // Metrics that need no window still work on the small image.
    const CommandResult r = runCompare(dir, {tiny, tiny, "--metric", "rmse"});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(r.out, "rmse 0\n");
}

TEST(CliCompare, HeatmapIsWrittenForTheComparedRegionAndNothingElseIsLeft) {
    const fs::path dir = scratchDirectory();
    const std::string refPath = writeImage(dir, "ref.exr", texturedImage(16, 12, 0.0f));
    const std::string testPath = writeImage(dir, "test.exr", texturedImage(16, 12, 0.5f));
    const CommandResult r = runCompare(dir, {testPath, refPath, "--heatmap", "heat.png", "--crop", "2,3,10,6"});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    ASSERT_TRUE(fs::exists(dir / "heat.png"));
    const ImageChannels heat = readExr((dir / "heat.png").string());
    EXPECT_EQ(heat.width, 10);
    EXPECT_EQ(heat.height, 6);
    std::vector<std::string> names;
    for (const auto& entry : fs::directory_iterator(dir)) names.push_back(entry.path().filename().string());
    std::sort(names.begin(), names.end());
    EXPECT_EQ(names, (std::vector<std::string>{"heat.png", "logs", "ref.exr", "test.exr"}));
}

TEST(CliCompare, PngInputsAreLinearised) {
    // The same image as EXR and as 8-bit sRGB PNG compares as nearly equal;
    // read without decoding, mid-grey 0.2 would come back as ~0.48.
    const fs::path dir = scratchDirectory();
    ImageChannels image;
    image.width = 12;
    image.height = 12;
    image.rgb.assign(144, Rgb(0.2f, 0.5f, 0.8f));
    const std::string exrPath = writeImage(dir, "image.exr", image);
    writePngPreview((dir / "image.png").string(), image);
    const CommandResult r = runCompare(dir, {(dir / "image.png").string(), exrPath, "--metric", "mae"});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    const auto lines = parseLines(r.out);
    ASSERT_EQ(lines.size(), 1u);
    EXPECT_LT(lines[0].second, 0.005);
}

}  // namespace
}  // namespace fg
