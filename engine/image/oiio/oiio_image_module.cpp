// The OpenImageIO reader, built as a module (libfluxgraph_oiio.so) that the
// program loads only when it reads an image that is not EXR. OpenImageIO
// brings about 260 shared libraries; mapped at start-up they were most of
// the program's memory before any work.
#include "engine/image/image_file_input.h"

#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace {

fg::SampleType sampleTypeOf(OIIO::TypeDesc format) {
    switch (format.basetype) {
    case OIIO::TypeDesc::HALF:
    case OIIO::TypeDesc::FLOAT:
    case OIIO::TypeDesc::DOUBLE: return fg::SampleType::Float;
    case OIIO::TypeDesc::UINT8: return fg::SampleType::UInt8;
    case OIIO::TypeDesc::UINT16: return fg::SampleType::UInt16;
    default: return fg::SampleType::OtherInteger;
    }
}

class OiioImageFileInput final : public fg::ImageFileInput {
public:
    explicit OiioImageFileInput(std::unique_ptr<OIIO::ImageInput> input) : input_(std::move(input)) {
        const OIIO::ImageSpec& spec = input_->spec();
        spec_.formatName = input_->format_name();
        spec_.width = spec.width;
        spec_.height = spec.height;
        spec_.depth = spec.depth;
        spec_.channelNames.assign(spec.channelnames.begin(), spec.channelnames.end());
        spec_.channelNames.resize(static_cast<std::size_t>(std::max(spec.nchannels, 0)));
        spec_.sampleType = sampleTypeOf(spec.format);
        spec_.colorSpace = spec.get_string_attribute("oiio:ColorSpace");
    }
    ~OiioImageFileInput() override { input_->close(); }

    const fg::ImageFileSpec& spec() const override { return spec_; }

    bool readPixels(int channels, float* pixels) override {
        return input_->read_image(0, 0, 0, channels, OIIO::TypeDesc::FLOAT, pixels);
    }

    std::string error() override { return input_->geterror(); }

    std::vector<std::pair<std::string, std::string>> stringAttributes(const std::string& prefix) override {
        std::vector<std::pair<std::string, std::string>> found;
        for (const OIIO::ParamValue& attribute : input_->spec().extra_attribs) {
            std::string name = attribute.name().string();
            if (attribute.type() != OIIO::TypeDesc::STRING || name.rfind(prefix, 0) != 0) continue;
            found.emplace_back(std::move(name), attribute.get_string());
        }
        return found;
    }

private:
    std::unique_ptr<OIIO::ImageInput> input_;
    fg::ImageFileSpec spec_;
};

}  // namespace

extern "C" __attribute__((visibility("default"))) fg::ImageFileInput* fluxgraph_open_image_with_oiio(
    const char* path, std::string* error) {
    std::unique_ptr<OIIO::ImageInput> input = OIIO::ImageInput::open(path);
    if (!input) {
        *error = OIIO::geterror();
        return nullptr;
    }
    return new OiioImageFileInput(std::move(input));
}
