#include "engine/image/image_file_input.h"

#include "engine/image/image_io.h"
#include "tests/support/cli_helpers.h"

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

namespace fg {
namespace {

namespace fs = std::filesystem;

ImageChannels gradient(int width, int height) {
    ImageChannels image;
    image.width = width;
    image.height = height;
    std::vector<float> samples;
    for (int y = 0; y < height; ++y) {
        for (int x = 0; x < width; ++x) {
            image.rgb.emplace_back(0.1f * static_cast<float>(x), std::sin(static_cast<float>(y)),
                                   1.0f / (1.0f + static_cast<float>(x * y)));
            samples.push_back(static_cast<float>(x + y));
        }
    }
    image.extra = {{"time_ns", std::vector<float>(samples.size(), 70000.5f)}, {"samples", samples}};
    return image;
}

// OpenEXR lists channels alphabetically (B, G, R, samples, time_ns); readers
// take the first three as the colour, so R, G, B come first, as OpenImageIO put them.
TEST(ImageFileInput, ExrChannelsComeColourFirstWithTheFilesStringAttributes) {
    const fs::path dir = test::scratchDirectory("image_file_input");
    const std::string path = (dir / "render.exr").string();
    writeExr(path, gradient(5, 3), {{"seed", "7"}});
    std::string error;
    const std::unique_ptr<ImageFileInput> input = openImageFile(path, error);
    ASSERT_TRUE(input) << error;
    EXPECT_EQ(input->spec().formatName, "openexr");
    EXPECT_EQ(input->spec().channelNames, (std::vector<std::string>{"R", "G", "B", "samples", "time_ns"}));
    EXPECT_EQ(input->spec().sampleType, SampleType::Float);
    const auto attributes = input->stringAttributes("fluxgraph:");
    ASSERT_EQ(attributes.size(), 1u);
    EXPECT_EQ(attributes[0], (std::pair<std::string, std::string>{"fluxgraph:seed", "7"}));
}

// Half colour is rounded as OpenImageIO rounds it: both readers see the same values.
TEST(ImageFileInput, HalfExrReadsAsOpenImageIoReadsIt) {
    const fs::path dir = test::scratchDirectory("image_file_input");
    const std::string path = (dir / "half.exr").string();
    const ImageChannels written = gradient(7, 4);
    writeExr(path, written, {}, true);
    const ImageChannels read = readExr(path);
    auto reference = OIIO::ImageInput::open(path);
    ASSERT_TRUE(reference);
    std::vector<float> pixels(static_cast<std::size_t>(7 * 4 * 5));
    ASSERT_TRUE(reference->read_image(0, 0, 0, 5, OIIO::TypeDesc::FLOAT, pixels.data()));
    for (std::size_t p = 0; p < read.rgb.size(); ++p) {
        for (int c = 0; c < 3; ++c) EXPECT_EQ(read.rgb[p][c], pixels[p * 5 + static_cast<std::size_t>(c)]) << p;
        EXPECT_EQ(read.extra[0].second[p], pixels[p * 5 + 3]) << p;
        EXPECT_EQ(read.extra[1].second[p], pixels[p * 5 + 4]) << p;
    }
    EXPECT_NE(read.rgb[1].x, written.rgb[1].x);  // 0.1 is not a half
}

// Formats other than EXR go through the OpenImageIO module.
TEST(ImageFileInput, PngIsReadThroughTheOpenImageIoModuleAsSrgbBytes) {
    const fs::path dir = test::scratchDirectory("image_file_input");
    const std::string path = (dir / "preview.png").string();
    writePngPreview(path, gradient(6, 2));
    std::string error;
    const std::unique_ptr<ImageFileInput> input = openImageFile(path, error);
    ASSERT_TRUE(input) << error;
    EXPECT_EQ(input->spec().formatName, "png");
    EXPECT_EQ(input->spec().width, 6);
    EXPECT_EQ(input->spec().height, 2);
    EXPECT_EQ(input->spec().sampleType, SampleType::UInt8);
    EXPECT_EQ(input->spec().colorSpace, "sRGB");
    std::vector<float> pixels(6 * 2 * 3);
    ASSERT_TRUE(input->readPixels(3, pixels.data())) << input->error();
    EXPECT_EQ(pixels[0], 0.0f);
    EXPECT_EQ(pixels[2], 1.0f);  // blue 1 / (1 + 0)
}

TEST(ImageFileInput, AFileThatIsNoImageIsRefusedWithTheReason) {
    const fs::path dir = test::scratchDirectory("image_file_input");
    test::writeText(dir / "notes.png", "not an image");
    std::string error;
    EXPECT_FALSE(openImageFile((dir / "notes.png").string(), error));
    EXPECT_FALSE(error.empty());
    test::writeText(dir / "broken.exr", std::string("\x76\x2f\x31\x01", 4) + "rest");
    EXPECT_FALSE(openImageFile((dir / "broken.exr").string(), error));
    EXPECT_FALSE(error.empty());
}

}  // namespace
}  // namespace fg
