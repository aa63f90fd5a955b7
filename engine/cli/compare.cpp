// The `compare` subcommand: reads a test image and a reference, prints the
// metrics of engine/image/image_compare.h as machine-readable "name value" lines
// and optionally writes a relative-error heatmap. Every failure is found
// before anything is printed, so a run either prints all requested lines or
// exactly one error line (exit code 2).
#include "engine/cli/compare.h"

#include "engine/core/error.h"
#include "engine/image/image_compare.h"

#include <CLI/CLI.hpp>

#include <charconv>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <optional>
#include <utility>
#include <vector>

namespace fg::cli {

namespace {

constexpr int kInputErrorExit = 2;

CropRect parseCrop(const std::string& text) {
    const auto fail = [&]() -> CropRect {
        throw InputError("--crop '" + text + "': expected x,y,width,height (four integers)");
    };
    int values[4] = {};
    const char* cursor = text.data();
    const char* const end = text.data() + text.size();
    for (int i = 0; i < 4; ++i) {
        const auto [next, error] = std::from_chars(cursor, end, values[i]);
        if (error != std::errc() || next == cursor) return fail();
        cursor = next;
        if (i < 3) {
            if (cursor == end || *cursor != ',') return fail();
            ++cursor;
        }
    }
    if (cursor != end) return fail();
    return CropRect{values[0], values[1], values[2], values[3]};
}

// Library and OpenImageIO messages may span lines; the CLI promises one.
std::string oneLine(std::string message) {
    for (char& c : message)
        if (c == '\n' || c == '\r') c = ' ';
    while (!message.empty() && message.back() == ' ') message.pop_back();
    return printableMessage(message);
}

std::string formatValue(double value) {
    if (std::isnan(value)) return "nan";  // glibc would print a negative nan as "-nan"
    char buffer[64];
    std::snprintf(buffer, sizeof buffer, "%.10g", value);
    return buffer;
}

}  // namespace

CLI::App* addCompareSubcommand(CLI::App& app, CompareOptions& options) {
    CLI::App* compare = app.add_subcommand("compare", "error metrics of an image against a reference");
    compare->add_option("test", options.testPath, "image to judge (EXR; PNG and other formats via OpenImageIO)")
        ->required();
    compare->add_option("reference", options.referencePath, "reference image, same size")->required();
    compare->add_option("--metric", options.metric, "metric line(s) to print")
        ->check(CLI::IsMember({"rmse", "relmse", "mae", "ssim", "psnr", "worst_relse", "all"}));
    compare->add_option("--heatmap", options.heatmapPath, "write a false-colour relative-error PNG");
    compare->add_option("--crop", options.crop, "compare only the rectangle x,y,width,height (y down from the top)");
    return compare;
}

int runCompare(const CompareOptions& options) {
    try {
        std::optional<CropRect> crop;
        if (!options.crop.empty()) crop = parseCrop(options.crop);
        const ImageChannels test = readImageLinear(options.testPath);
        const ImageChannels reference = readImageLinear(options.referencePath);
        if (test.width != reference.width || test.height != reference.height)
            throw InputError(options.testPath, 0,
                             "size " + std::to_string(test.width) + "x" + std::to_string(test.height) +
                                 " differs from the reference " + options.referencePath + " (" +
                                 std::to_string(reference.width) + "x" + std::to_string(reference.height) + ")");
        const ImageMetrics metrics = compareImages(test, reference, crop);
        if (options.metric == "ssim" && std::isnan(metrics.ssim)) {
            const int width = crop ? crop->width : test.width;
            const int height = crop ? crop->height : test.height;
            throw InputError("ssim needs a region of at least " + std::to_string(2 * kSsimWindowRadius + 1) + "x" +
                             std::to_string(2 * kSsimWindowRadius + 1) + " pixels, got " + std::to_string(width) +
                             "x" + std::to_string(height));
        }
        if (!options.heatmapPath.empty()) writeRelativeErrorHeatmap(options.heatmapPath, test, reference, crop);

        const std::vector<std::pair<const char*, double>> lines = {
            {"rmse", metrics.rmse}, {"relmse", metrics.relmse}, {"mae", metrics.mae},
            {"ssim", metrics.ssim}, {"psnr", metrics.psnr}, {"worst_relse", metrics.worstRelse},
        };
        for (const auto& [name, value] : lines)
            if (options.metric == "all" || options.metric == name) std::cout << name << ' ' << formatValue(value) << '\n';
        return 0;
    } catch (const InputError& e) {
        std::cerr << oneLine(e.what()) << '\n';
        return kInputErrorExit;
    }
}

}  // namespace fg::cli
