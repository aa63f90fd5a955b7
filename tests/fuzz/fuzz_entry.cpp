#include "tests/fuzz/fuzz_entry.h"

#include "engine/core/error.h"
#include "engine/core/job.h"
#include "engine/core/pass.h"
#include "engine/scene/scene_loader.h"
#include "engine/scene/shape.h"
#include "engine/shading/light.h"
#include "engine/shading/texture.h"
#include "passes/passes.h"

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <string>
#include <system_error>

namespace fg::fuzz {

namespace {

namespace fs = std::filesystem;

// One private directory per process, made on first use and removed at exit:
// the loaders that take a path read the bytes from a file in it, and paths
// that the input names relative to its own file (meshes, includes) resolve
// there and find nothing but the input itself.
class ScratchDirectory {
public:
    ScratchDirectory() {
        const char* base = std::getenv("TMPDIR");
        std::string pattern = std::string(base && *base ? base : "/tmp") + "/fluxgraph-fuzz-XXXXXX";
        if (!::mkdtemp(pattern.data())) throw std::runtime_error("fuzz: cannot create a directory under " + pattern);
        path_ = pattern;
    }
    ~ScratchDirectory() {
        std::error_code ignored;
        fs::remove_all(path_, ignored);
    }
    ScratchDirectory(const ScratchDirectory&) = delete;
    ScratchDirectory& operator=(const ScratchDirectory&) = delete;

    // Replaces the file `name` by `bytes`; returns its path.
    std::string write(const std::string& name, std::span<const std::uint8_t> bytes) const {
        const fs::path file = path_ / name;
        std::ofstream out(file, std::ios::binary | std::ios::trunc);
        out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
        out.close();
        if (!out) throw std::runtime_error("fuzz: cannot write " + file.string());
        return file.string();
    }

private:
    fs::path path_;
};

const ScratchDirectory& scratch() {
    static const ScratchDirectory directory;
    return directory;
}

std::string asText(std::span<const std::uint8_t> bytes) {
    return std::string(reinterpret_cast<const char*>(bytes.data()), bytes.size());
}

template <typename Load>
Verdict refusedOnInputError(Load&& load) {
    try {
        load();
        return Verdict::Accepted;
    } catch (const InputError&) {
        return Verdict::Refused;
    }
}

// Image readers are chosen by extension (OpenImageIO tries the others only
// after that one fails), so the file is named after its signature, as a user's
// texture would be; anything unrecognised is offered as PNG.
std::string imageFileName(std::span<const std::uint8_t> bytes) {
    const auto startsWith = [&](std::string_view magic) {
        return bytes.size() >= magic.size() && asText(bytes.first(magic.size())) == magic;
    };
    if (startsWith("\x76\x2f\x31\x01")) return "image.exr";
    if (startsWith("#?")) return "image.hdr";
    if (startsWith("\xff\xd8")) return "image.jpg";
    if (startsWith("Pf") || startsWith("PF")) return "image.pfm";
    if (startsWith("P1") || startsWith("P2") || startsWith("P3") || startsWith("P4") || startsWith("P5") ||
        startsWith("P6"))
        return "image.ppm";
    return "image.png";
}

constexpr Target kTargets[] = {
    {"job", fuzzJob}, {"toml_scene", fuzzTomlScene}, {"xml_scene", fuzzXmlScene},
    {"obj", fuzzObj}, {"ply", fuzzPly},              {"image", fuzzImage},
};

}  // namespace

Verdict fuzzJob(std::span<const std::uint8_t> bytes) {
    const Registry& registry = builtinRegistry();
    installRegistry(&registry);
    const std::string path = scratch().write("job.toml", bytes);
    return refusedOnInputError([&] {
        const Job job = parseJob(asText(bytes), path, {}, registry);
        ExecutionPlan::build(job.pipeline, job.params, job.path, registry.passes, job.bufferFiles);
    });
}

Verdict fuzzTomlScene(std::span<const std::uint8_t> bytes) {
    const std::string path = scratch().write("scene.toml", bytes);
    return refusedOnInputError([&] { loadScene(path); });
}

Verdict fuzzXmlScene(std::span<const std::uint8_t> bytes) {
    const std::string path = scratch().write("scene.xml", bytes);
    return refusedOnInputError([&] { loadScene(path); });
}

Verdict fuzzObj(std::span<const std::uint8_t> bytes) {
    const std::string path = scratch().write("mesh.obj", bytes);
    return refusedOnInputError([&] { loadObjMesh(path); });
}

Verdict fuzzPly(std::span<const std::uint8_t> bytes) {
    const std::string path = scratch().write("mesh.ply", bytes);
    return refusedOnInputError([&] { loadPlyMesh(path); });
}

Verdict fuzzImage(std::span<const std::uint8_t> bytes) {
    const std::string path = scratch().write(imageFileName(bytes), bytes);
    return refusedOnInputError([&] {
        RgbImage image = readRgbImage(path);
        // Both users of an image: the environment map builds its sampling
        // distribution over every pixel, the texture looks one up.
        makeEnvironmentMap(image, 1.0f);
        makeBitmapTexture(std::move(image))->eval(Vec2(0.25f, 0.75f));
    });
}

std::span<const Target> targets() { return kTargets; }

}  // namespace fg::fuzz
