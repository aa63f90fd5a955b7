#include "engine/image/image_io.h"

#include "engine/core/error.h"
#include "engine/image/image_compare.h"
#include "tests/support/cli_helpers.h"

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <stdexcept>

namespace fg {
namespace {

namespace fs = std::filesystem;

// A fresh, empty directory per test.
fs::path scratchDirectory() { return test::scratchDirectory("image_io"); }

std::vector<std::string> listDirectory(const fs::path& dir) {
    std::vector<std::string> names;
    for (const auto& entry : fs::directory_iterator(dir)) names.push_back(entry.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
}

ImageChannels testImage(int width, int height) {
    ImageChannels image;
    image.width = width;
    image.height = height;
    const std::size_t pixels = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
    std::vector<float> time(pixels), samples(pixels);
    for (std::size_t p = 0; p < pixels; ++p) {
        const float t = static_cast<float>(p);
        // Values spanning many magnitudes, including ones half cannot store exactly.
        image.rgb.emplace_back(0.001f * t, std::sin(t) * 3.0f, 1000.0f / (1.0f + t));
        time[p] = 12345.678f + t * 0.1f;
        samples[p] = static_cast<float>(p % 7);
    }
    image.extra = {{"time_ns", time}, {"samples", samples}};
    return image;
}

const std::vector<float>& channel(const ImageChannels& image, const std::string& name) {
    for (const auto& [n, values] : image.extra)
        if (n == name) return values;
    throw std::runtime_error("missing channel " + name);
}

TEST(ImageIo, ExrRoundTripKeepsValuesChannelsAndMetadata) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "render.exr").string();
    const ImageChannels image = testImage(23, 9);
    const Metadata metadata = {{"scene", "cornell box"}, {"seed", "42"}, {"pass.order", "photons,gather"}};
    writeExr(path, image, metadata);
    EXPECT_EQ(listDirectory(dir), std::vector<std::string>{"render.exr"});

    Metadata readBack;
    const ImageChannels read = readExr(path, &readBack);
    ASSERT_EQ(read.width, 23);
    ASSERT_EQ(read.height, 9);
    ASSERT_EQ(read.rgb.size(), image.rgb.size());
    for (std::size_t p = 0; p < image.rgb.size(); ++p) {
        EXPECT_EQ(read.rgb[p].x, image.rgb[p].x) << p;
        EXPECT_EQ(read.rgb[p].y, image.rgb[p].y) << p;
        EXPECT_EQ(read.rgb[p].z, image.rgb[p].z) << p;
    }
    ASSERT_EQ(read.extra.size(), 2u);
    EXPECT_EQ(channel(read, "time_ns"), channel(image, "time_ns"));
    EXPECT_EQ(channel(read, "samples"), channel(image, "samples"));

    const std::map<std::string, std::string> expected(metadata.begin(), metadata.end());
    const std::map<std::string, std::string> actual(readBack.begin(), readBack.end());
    EXPECT_EQ(actual, expected);
    EXPECT_EQ(readBack.size(), metadata.size());

    // The file really is ZIP-compressed float EXR.
    auto input = OIIO::ImageInput::open(path);
    ASSERT_TRUE(input);
    EXPECT_EQ(input->format_name(), std::string("openexr"));
    EXPECT_EQ(input->spec().format, OIIO::TypeDesc::FLOAT);
    EXPECT_EQ(input->spec().get_string_attribute("compression"), "zip");
}

TEST(ImageIo, HalfExrIsWithinHalfPrecision) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "reference.exr").string();
    const ImageChannels image = testImage(16, 16);
    writeExr(path, image, {}, /*halfFloat=*/true);
    {
        auto input = OIIO::ImageInput::open(path);
        ASSERT_TRUE(input);
        // Colour in half; the AOVs (time_ns exceeds half's range) stay 32-bit float.
        const OIIO::ImageSpec& spec = input->spec();
        ASSERT_EQ(spec.nchannels, 5);
        for (int c = 0; c < 3; ++c) EXPECT_EQ(spec.channelformat(c), OIIO::TypeDesc::HALF) << spec.channelnames[c];
        for (int c = 3; c < 5; ++c) EXPECT_EQ(spec.channelformat(c), OIIO::TypeDesc::FLOAT) << spec.channelnames[c];
    }
    const ImageChannels read = readExr(path);
    // Half has an 11-bit significand: relative rounding error at most 2^-11
    // for normal numbers; smaller values (subnormals below 6.1e-5) get an absolute bound.
    auto close = [](float actual, float expected) {
        return std::abs(actual - expected) <= std::max(std::abs(expected) * 0x1p-11f, 0x1p-24f);
    };
    bool anyRounded = false;
    for (std::size_t p = 0; p < image.rgb.size(); ++p) {
        for (int c = 0; c < 3; ++c) {
            EXPECT_TRUE(close(read.rgb[p][c], image.rgb[p][c])) << p << ": " << read.rgb[p][c] << " vs " << image.rgb[p][c];
            anyRounded |= read.rgb[p][c] != image.rgb[p][c];
        }
    }
    EXPECT_TRUE(anyRounded) << "values were not stored at half precision";
    EXPECT_EQ(channel(read, "time_ns"), channel(image, "time_ns"));
    EXPECT_EQ(channel(read, "samples"), channel(image, "samples"));
}

TEST(ImageIo, PngPreviewIsSrgbEncoded) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "preview.png").string();
    ImageChannels image;
    image.width = 4;
    image.height = 2;
    // Reference pairs from the sRGB definition (IEC 61966-2-1): linear 0.18 -> 118,
    // 0.5 -> 188, 0.216 -> 128 (mid grey), 0.002 -> 7 (linear segment).
    image.rgb = {Rgb(0.0f, 1.0f, 0.5f),  Rgb(0.18f, 0.216f, 0.002f), Rgb(-1.0f, 7.0f, NAN), Rgb(0.25f, 0.09f, 0.108f),
                 Rgb(1.0f, 0.5f, 0.0f), Rgb(0.0f, 0.0f, 0.0f),         Rgb(0.0f, 0.0f, 0.0f), Rgb(0.0f, 0.0f, 0.0f)};
    writePngPreview(path, image);
    const std::string brighter = (dir / "brighter.png").string();
    writePngPreview(brighter, image, 1.0f);

    auto readBytes = [](const std::string& file) {
        auto input = OIIO::ImageInput::open(file);
        EXPECT_TRUE(input);
        EXPECT_EQ(input->spec().nchannels, 3);
        std::vector<unsigned char> bytes(static_cast<std::size_t>(input->spec().image_pixels()) * 3);
        EXPECT_TRUE(input->read_image(0, 0, 0, 3, OIIO::TypeDesc::UINT8, bytes.data()));
        return bytes;
    };
    const std::vector<unsigned char> plain = readBytes(path);
    const std::vector<unsigned char> expected = {0, 255, 188, 118, 128, 7, 0, 255, 0};
    for (std::size_t i = 0; i < expected.size(); ++i) EXPECT_EQ(int(plain[i]), int(expected[i])) << i;
    // Top-left pixel first: the second row starts with (1, 0.5, 0).
    EXPECT_EQ(int(plain[12]), 255);
    EXPECT_EQ(int(plain[13]), 188);

    // One stop up doubles linear values: 0.25 -> 0.5 -> 188, 0.108 -> 0.216 -> 128.
    const std::vector<unsigned char> doubled = readBytes(brighter);
    EXPECT_EQ(int(doubled[9]), 188);
    EXPECT_EQ(int(doubled[11]), 128);
    EXPECT_EQ(int(doubled[2]), 255);  // 0.5 * 2 = 1 -> white
}

TEST(ImageIo, TemporaryPathStaysInTheDirectoryAndKeepsTheExtension) {
    const std::string a = temporaryPathFor("/some/dir/out.exr");
    const std::string b = temporaryPathFor("/some/dir/out.exr");
    EXPECT_NE(a, b);
    EXPECT_EQ(fs::path(a).parent_path(), fs::path("/some/dir"));
    EXPECT_EQ(fs::path(a).extension(), ".exr");
    EXPECT_NE(fs::path(a).filename().string().find(".tmp-"), std::string::npos);
    EXPECT_EQ(fs::path(temporaryPathFor("preview.png")).parent_path(), fs::path());
}

TEST(ImageIo, WriterThatThrowsLeavesNoFile) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "result.exr").string();
    std::string used;
    EXPECT_THROW(writeAtomically(path,
                                 [&](const std::string& temporary) {
                                     used = temporary;
                                     std::ofstream(temporary) << "partial";
                                     throw std::runtime_error("interrupted");
                                 }),
                 std::runtime_error);
    EXPECT_TRUE(fs::path(used).parent_path() == dir);
    EXPECT_TRUE(listDirectory(dir).empty());

    writeAtomically(path, [](const std::string& temporary) { std::ofstream(temporary) << "complete"; });
    EXPECT_EQ(listDirectory(dir), std::vector<std::string>{"result.exr"});
}

TEST(ImageIo, WritingIntoAMissingDirectoryThrowsInputError) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "missing" / "out.exr").string();
    try {
        writeExr(path, testImage(4, 4), {});
        FAIL() << "no error";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    }
    EXPECT_THROW(writePngPreview((dir / "missing" / "out.png").string(), testImage(4, 4)), InputError);
    EXPECT_TRUE(listDirectory(dir).empty());
}

TEST(ImageIo, WritingUnderAFileOrOntoADirectoryThrowsAndLeavesNothing) {
    const fs::path dir = scratchDirectory();
    std::ofstream(dir / "plain") << "x";
    EXPECT_THROW(writeExr((dir / "plain" / "out.exr").string(), testImage(4, 4), {}), InputError);
    // The final name is an existing directory: the image is written, the rename fails.
    fs::create_directories(dir / "taken.exr");
    try {
        writeExr((dir / "taken.exr").string(), testImage(4, 4), {});
        FAIL() << "no error";
    } catch (const InputError& e) {
        EXPECT_NE(std::string(e.what()).find("taken.exr"), std::string::npos) << e.what();
    }
    EXPECT_EQ(listDirectory(dir), (std::vector<std::string>{"plain", "taken.exr"}));
    EXPECT_TRUE(fs::is_empty(dir / "taken.exr"));
}

TEST(ImageIo, WritingIntoAReadOnlyDirectoryThrowsAndLeavesNothing) {
    const fs::path dir = scratchDirectory();
    const fs::path locked = dir / "locked";
    fs::create_directories(locked);
    fs::permissions(locked, fs::perms::owner_read | fs::perms::owner_exec);
    {
        // Privileged users ignore permission bits; then there is nothing to test here.
        std::ofstream probe(locked / "probe");
        if (probe) {
            probe.close();
            fs::remove(locked / "probe");
            fs::permissions(locked, fs::perms::owner_all);
            GTEST_SKIP() << "directory permissions are not enforced for this user";
        }
    }
    EXPECT_THROW(writeExr((locked / "out.exr").string(), testImage(4, 4), {}), InputError);
    fs::permissions(locked, fs::perms::owner_all);
    EXPECT_TRUE(fs::is_empty(locked));
}

TEST(ImageIo, ReadingAMissingFileThrowsInputError) {
    const fs::path dir = scratchDirectory();
    EXPECT_THROW(readExr((dir / "absent.exr").string()), InputError);
}

// The damaged images found by fuzzing the texture reader (tests/fuzz/regressions/image/)
// reach the readers of references and of `fluxgraph compare` too: each must be
// refused with an InputError, and those whose header or structure claims more
// than the file holds by the size checks, before anything is allocated at the
// claimed size.
TEST(ImageIo, DamagedImagesAreRefusedBeforeTheirClaimedSizesAreAllocated) {
    const fs::path regressions = fs::path(FLUXGRAPH_SOURCE_DIR) / "tests" / "fuzz" / "regressions" / "image";
    std::size_t checked = 0;
    for (const fs::directory_entry& entry : fs::directory_iterator(regressions)) {
        const std::string name = entry.path().filename().string();
        if (name.rfind("bad-", 0) != 0) continue;
        const bool sizeClaim = name.find("attribute") != std::string::npos || name.find("huge") != std::string::npos ||
                               name.find("chunk") != std::string::npos || name.find("claims") != std::string::npos;
        for (const bool linear : {false, true}) {
            SCOPED_TRACE(name + (linear ? " (readImageLinear)" : " (readExr)"));
            try {
                if (linear)
                    readImageLinear(entry.path().string());
                else
                    readExr(entry.path().string());
                ADD_FAILURE() << "accepted";
            } catch (const InputError& error) {
                const std::string message = error.what();
                if (sizeClaim) {
                    EXPECT_TRUE(message.find("more than the file holds") != std::string::npos ||
                                message.find("over the limit") != std::string::npos ||
                                message.find("bytes of data, the file has") != std::string::npos)
                        << message;
                }
            }
        }
        ++checked;
    }
    EXPECT_GE(checked, 10u);
}

}  // namespace
}  // namespace fg
