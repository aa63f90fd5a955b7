// Buffer files: every buffer type survives save, load and save again bit for
// bit, and damaged, foreign or mistyped files are refused with one line that
// names the file, never with a crash or a huge allocation.
#include "engine/core/codec.h"

#include "engine/accel/photon_bvh.h"
#include "engine/accel/point_index.h"
#include "engine/buffers/beam_buffers.h"
#include "engine/buffers/photon_buffers.h"
#include "engine/core/error.h"
#include "engine/image/film.h"
#include "tests/support/cli_helpers.h"
#include "tests/support/input_error.h"

#include "tests/support/pass_helpers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <random>
#include <string>
#include <vector>

namespace fg {
namespace {

namespace fs = std::filesystem;

// A fresh, empty directory per test.
fs::path scratchDirectory() { return test::scratchDirectory("codec"); }

std::string readBytes(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writeBytes(const fs::path& path, const std::string& bytes) {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

using test::makeBuffer;

// Bitwise, so that NaNs, infinities and signed zeros count.
template <class T>
void expectSameBits(std::span<const T> a, std::span<const T> b, const std::string& what) {
    ASSERT_EQ(a.size(), b.size()) << what;
    EXPECT_TRUE(a.empty() || std::memcmp(a.data(), b.data(), a.size_bytes()) == 0) << what;
}

template <class... Columns>
void expectSameSoa(const SoaBuffer<Columns...>& a, const SoaBuffer<Columns...>& b) {
    ASSERT_EQ(a.size(), b.size());
    (expectSameBits(a.template column<Columns>(), b.template column<Columns>(), Columns::name), ...);
}

class Random {
public:
    explicit Random(unsigned seed) : engine_(seed) {}
    float uniform(float lo = 0.0f, float hi = 1.0f) { return std::uniform_real_distribution<float>(lo, hi)(engine_); }
    Vec3 vec3(float lo = -1.0f, float hi = 1.0f) { return Vec3(uniform(lo, hi), uniform(lo, hi), uniform(lo, hi)); }
    std::uint32_t below(std::uint32_t n) { return std::uniform_int_distribution<std::uint32_t>(0, n - 1)(engine_); }
    std::mt19937& engine() { return engine_; }

private:
    std::mt19937 engine_;
};

// --- Buffers with random contents --------------------------------------------

Film makeFilm(unsigned seed) {
    Random random(seed);
    FilmSettings settings;
    settings.width = 7;
    settings.height = 5;
    settings.filter = FilterKind::Gaussian;
    settings.filterRadius = 1.5f;
    settings.gaussianSigma = 0.6f;
    Film film(settings);
    const int spp = 2;
    std::vector<Vec2> raster;
    std::vector<Rgb> radiance;
    for (int y = 0; y < settings.height; ++y)
        for (int x = 0; x < settings.width; ++x)
            for (int s = 0; s < spp; ++s) {
                raster.emplace_back(static_cast<float>(x) + random.uniform(), static_cast<float>(y) + random.uniform());
                radiance.push_back(random.vec3(0.0f, 4.0f));
            }
    film.addRound(SampleRound{0, film.pixelCount(), spp, raster, radiance});
    std::vector<Rgb> direct(film.pixelCount());
    for (Rgb& value : direct) value = random.vec3(0.0f, 1.0f);
    film.addToPixels(direct, 0.5f);
    for (float& value : film.aov("time_ns")) value = random.uniform(0.0f, 1e6f);
    for (float& value : film.aov("samples")) value = static_cast<float>(random.below(100));
    return film;
}

PhotonMap makePhotonMap(unsigned seed, std::size_t count = 50) {
    Random random(seed);
    PhotonMap map;
    map.photons.resize(count);
    for (std::size_t i = 0; i < count; ++i) {
        map.photons.column<PhotonPosition>()[i] = random.vec3();
        map.photons.column<PhotonIncident>()[i] = glm::normalize(random.vec3());
        map.photons.column<PhotonPower>()[i] = random.vec3(0.0f, 1e-3f);
        map.photons.column<PhotonNormal>()[i] = glm::normalize(random.vec3());
        map.photons.column<PhotonClassColumn>()[i] = static_cast<std::uint8_t>(1u << random.below(4));
        map.photons.column<PhotonDu>()[i] = random.vec3(-0.01f, 0.01f);
        map.photons.column<PhotonDv>()[i] = random.vec3(-0.01f, 0.01f);
    }
    map.emitted = 1234567;
    map.collapsedFootprints = 7;
    map.hasDifferentials = true;
    return map;
}

EyeVertices makeEyeVertices(unsigned seed) {
    Random random(seed);
    EyeVertices eye;
    eye.samplesPerPixel = 3;
    eye.vertices.resize(40);
    for (std::size_t i = 0; i < eye.vertices.size(); ++i) {
        eye.vertices.column<EyePosition>()[i] = random.vec3();
        eye.vertices.column<EyeNormal>()[i] = glm::normalize(random.vec3());
        eye.vertices.column<EyeGeometricNormal>()[i] = glm::normalize(random.vec3());
        eye.vertices.column<EyeOutgoing>()[i] = glm::normalize(random.vec3());
        eye.vertices.column<EyeBsdf>()[i] = random.below(5);
        eye.vertices.column<EyeUv>()[i] = Vec2(random.uniform(), random.uniform());
        eye.vertices.column<EyeThroughput>()[i] = random.vec3(0.0f, 1.0f);
        eye.vertices.column<EyePixel>()[i] = random.below(64);
    }
    return eye;
}

PhotonRadii makePhotonRadii(unsigned seed) {
    Random random(seed);
    PhotonRadii radii;
    radii.neighbours = 16;
    radii.scale = 1.25f;
    radii.radii.resize(30);
    for (float& r : radii.radii.column<PhotonRadius>()) r = random.uniform(0.001f, 0.1f);
    return radii;
}

EyeSegments makeEyeSegments(unsigned seed) {
    Random random(seed);
    EyeSegments segments;
    segments.samplesPerPixel = 2;
    segments.segments.resize(25);
    for (std::size_t i = 0; i < segments.segments.size(); ++i) {
        const float tNear = random.uniform(0.0f, 2.0f);
        segments.segments.column<SegmentOrigin>()[i] = random.vec3();
        segments.segments.column<SegmentDirection>()[i] = glm::normalize(random.vec3());
        segments.segments.column<SegmentTNear>()[i] = tNear;
        segments.segments.column<SegmentTFar>()[i] =
            i % 4 == 0 ? std::numeric_limits<float>::infinity() : tNear + random.uniform(0.0f, 3.0f);
        segments.segments.column<SegmentMedium>()[i] = static_cast<std::int32_t>(random.below(3));
        segments.segments.column<SegmentPixel>()[i] = random.below(64);
        segments.segments.column<SegmentThroughput>()[i] = random.vec3(0.0f, 1.0f);
    }
    return segments;
}

std::vector<Vec3> randomPoints(unsigned seed, std::size_t count) {
    Random random(seed);
    std::vector<Vec3> points(count);
    for (Vec3& p : points) p = random.vec3();
    return points;
}

// Indexes a subset (every third point) so that the id mapping is saved too.
PointIndex makePointIndex(unsigned seed) {
    const std::vector<Vec3> points = randomPoints(seed, 200);
    std::vector<std::uint32_t> ids;
    for (std::uint32_t i = 0; i < points.size(); i += 3) ids.push_back(i);
    PointIndex index;
    index.build(points, ids);
    return index;
}

PhotonBvh makePhotonBvh(unsigned seed) {
    const std::vector<Vec3> centers = randomPoints(seed, 300);
    Random random(seed + 1);
    std::vector<float> radii(centers.size());
    for (float& r : radii) r = random.uniform(0.01f, 0.1f);
    PhotonBvh::BuildOptions options;
    options.maxLeafSize = 4;
    PhotonBvh bvh;
    bvh.build(centers, radii, options);
    return bvh;
}

// --- Equality --------------------------------------------------------------

void expectSame(const Film& a, const Film& b) {
    EXPECT_EQ(a.settings().width, b.settings().width);
    EXPECT_EQ(a.settings().height, b.settings().height);
    EXPECT_EQ(a.settings().filter, b.settings().filter);
    EXPECT_EQ(a.settings().filterRadius, b.settings().filterRadius);
    EXPECT_EQ(a.settings().gaussianSigma, b.settings().gaussianSigma);
    EXPECT_EQ(a.hasDirect(), b.hasDirect());
    expectSameBits<Rgb>(a.weightedSums(), b.weightedSums(), "weighted sums");
    expectSameBits<float>(a.weightSums(), b.weightSums(), "weight sums");
    expectSameBits<Rgb>(a.directSums(), b.directSums(), "direct");
    ASSERT_EQ(a.aovs().size(), b.aovs().size());
    for (std::size_t i = 0; i < a.aovs().size(); ++i) {
        EXPECT_EQ(a.aovs()[i].first, b.aovs()[i].first);
        expectSameBits<float>(a.aovs()[i].second, b.aovs()[i].second, a.aovs()[i].first);
    }
    expectSameBits<Rgb>(a.resolve(), b.resolve(), "resolved image");
}

void expectSame(const PhotonMap& a, const PhotonMap& b) {
    EXPECT_EQ(a.emitted, b.emitted);
    EXPECT_EQ(a.collapsedFootprints, b.collapsedFootprints);
    EXPECT_EQ(a.hasDifferentials, b.hasDifferentials);
    expectSameSoa(a.photons, b.photons);
}

void expectSame(const EyeVertices& a, const EyeVertices& b) {
    EXPECT_EQ(a.samplesPerPixel, b.samplesPerPixel);
    expectSameSoa(a.vertices, b.vertices);
}

void expectSame(const PhotonRadii& a, const PhotonRadii& b) {
    EXPECT_EQ(a.neighbours, b.neighbours);
    EXPECT_EQ(a.scale, b.scale);
    expectSameSoa(a.radii, b.radii);
}

void expectSame(const EyeSegments& a, const EyeSegments& b) {
    EXPECT_EQ(a.samplesPerPixel, b.samplesPerPixel);
    expectSameSoa(a.segments, b.segments);
}

void expectSame(const PointIndex& a, const PointIndex& b) {
    EXPECT_EQ(a.size(), b.size());
    expectSameBits(a.ids(), b.ids(), "ids");
    EXPECT_EQ(a.tree().maxLeafSize(), b.tree().maxLeafSize());
    expectSameBits(a.tree().sortedPositions(), b.tree().sortedPositions(), "positions");
    expectSameBits(a.tree().permutation(), b.tree().permutation(), "permutation");
    expectSameBits(a.tree().splits(), b.tree().splits(), "splits");
    // And the queries agree.
    for (const Vec3& center : randomPoints(99, 20)) {
        std::uint32_t idsA[8], idsB[8];
        float distA[8], distB[8];
        const std::size_t foundA = a.nearest(center, 8, 0.5f, idsA, distA);
        const std::size_t foundB = b.nearest(center, 8, 0.5f, idsB, distB);
        ASSERT_EQ(foundA, foundB);
        EXPECT_TRUE(std::equal(idsA, idsA + foundA, idsB));
    }
}

void expectSame(const PhotonBvh& a, const PhotonBvh& b) {
    EXPECT_EQ(a.depth(), b.depth());
    expectSameSoa(a.nodes(), b.nodes());
    expectSameSoa(a.spheres(), b.spheres());
    for (const Vec3& origin : randomPoints(98, 20)) {
        const Vec3 direction = glm::normalize(-origin + Vec3(0.1f, 0.2f, 0.3f));
        std::vector<std::uint32_t> hitsA, hitsB;
        a.forEachSphereOnSegment(origin, direction, 0.0f, 3.0f, [&](std::uint32_t slot, float, float) {
            hitsA.push_back(slot);
        });
        b.forEachSphereOnSegment(origin, direction, 0.0f, 3.0f, [&](std::uint32_t slot, float, float) {
            hitsB.push_back(slot);
        });
        EXPECT_EQ(hitsA, hitsB);
    }
}

// Saves, loads, saves again: both files byte for byte equal, the loaded buffer
// equal to the original. Returns the first file's bytes.
template <class T>
std::string expectRoundTrip(std::shared_ptr<T> original, const fs::path& dir) {
    const std::string type = BufferTypeName<T>::value;
    const std::string first = (dir / (type + ".fgbuf")).string();
    const std::string second = (dir / (type + "-again.fgbuf")).string();
    const std::string job = "[job]\npipeline = \"test\"\n# " + type + "\n";
    saveBuffer(makeBuffer(original), first, job);
    const BufferHandle loaded = loadBuffer(first, type, "buffer");
    EXPECT_EQ(loaded.type, type);
    EXPECT_TRUE(loaded.bytes);
    if (!loaded.data) return {};
    expectSame(*original, test::bufferAs<T>(loaded));
    EXPECT_EQ(loaded.bytes(), test::bufferAs<T>(loaded).bytes());

    const BufferFileInfo info = readBufferInfo(first);
    EXPECT_EQ(info.type, type);
    EXPECT_EQ(info.jobText, job);
    saveBuffer(loaded, second, info.jobText);
    const std::string bytes = readBytes(first);
    EXPECT_EQ(bytes, readBytes(second)) << type;
    return bytes;
}

// Expects loadBuffer(path) to throw an InputError of one line starting "<path>: ".
std::string expectRefused(const std::string& path, const std::string& expectedType = "") {
    try {
        loadBuffer(path, expectedType);
    } catch (const InputError& error) {
        const std::string message = error.what();
        EXPECT_EQ(message.rfind(path + ": ", 0), 0u) << message;
        EXPECT_EQ(message.find('\n'), std::string::npos) << message;
        return message;
    } catch (const std::exception& error) {
        ADD_FAILURE() << "not an InputError: " << error.what();
        return {};
    }
    ADD_FAILURE() << path << " was accepted";
    return {};
}

// The buffers of every type, for the tests that run over all of them.
std::vector<std::pair<std::string, std::function<BufferHandle()>>> everyBuffer() {
    return {
        {"Film", [] { return makeBuffer(std::make_shared<Film>(makeFilm(1))); }},
        {"PhotonMap", [] { return makeBuffer(std::make_shared<PhotonMap>(makePhotonMap(2, 3))); }},
        {"EyeVertices", [] { return makeBuffer(std::make_shared<EyeVertices>(makeEyeVertices(3))); }},
        {"PhotonRadii", [] { return makeBuffer(std::make_shared<PhotonRadii>(makePhotonRadii(4))); }},
        {"EyeSegments", [] { return makeBuffer(std::make_shared<EyeSegments>(makeEyeSegments(5))); }},
        {"PointIndex", [] { return makeBuffer(std::make_shared<PointIndex>(makePointIndex(6))); }},
        {"PhotonBvh", [] { return makeBuffer(std::make_shared<PhotonBvh>(makePhotonBvh(7))); }},
    };
}

// --- Round trips -------------------------------------------------------------

TEST(CodecTypes, EveryBufferTypeHasACodec) {
    const std::vector<std::string> types = {
        BufferTypeName<Film>::value,        BufferTypeName<PhotonMap>::value,   BufferTypeName<EyeVertices>::value,
        BufferTypeName<PhotonRadii>::value, BufferTypeName<EyeSegments>::value, BufferTypeName<PointIndex>::value,
        BufferTypeName<PhotonBvh>::value,
    };
    const std::vector<std::string> registered = codecTypes();
    for (const std::string& type : types) {
        const BufferCodec* codec = findCodec(type);
        ASSERT_NE(codec, nullptr) << type;
        EXPECT_EQ(codec->type, type);
        EXPECT_NE(std::find(registered.begin(), registered.end(), type), registered.end()) << type;
    }
    EXPECT_EQ(findCodec("NoSuchBuffer"), nullptr);
    // Idempotent: registering the builtins again changes nothing.
    registerBuiltinCodecs();
    EXPECT_EQ(codecTypes(), registered);
}

TEST(CodecRoundTrip, Film) { expectRoundTrip(std::make_shared<Film>(makeFilm(11)), scratchDirectory()); }

TEST(CodecRoundTrip, FilmWithoutDirectOrAovs) {
    FilmSettings settings;
    settings.width = 3;
    settings.height = 2;
    auto film = std::make_shared<Film>(settings);
    const std::vector<Vec2> raster = {{0.5f, 0.5f}, {1.5f, 0.5f}, {2.5f, 0.5f},
                                      {0.5f, 1.5f}, {1.5f, 1.5f}, {2.5f, 1.5f}};
    const std::vector<Rgb> radiance(6, Rgb(1.0f, 2.0f, 3.0f));
    film->addRound(SampleRound{0, 6, 1, raster, radiance});
    expectRoundTrip(film, scratchDirectory());
}

TEST(CodecRoundTrip, PhotonMap) { expectRoundTrip(std::make_shared<PhotonMap>(makePhotonMap(12)), scratchDirectory()); }

TEST(CodecRoundTrip, EmptyPhotonMap) { expectRoundTrip(std::make_shared<PhotonMap>(), scratchDirectory()); }

TEST(CodecRoundTrip, EyeVertices) {
    expectRoundTrip(std::make_shared<EyeVertices>(makeEyeVertices(13)), scratchDirectory());
}

TEST(CodecRoundTrip, PhotonRadii) {
    expectRoundTrip(std::make_shared<PhotonRadii>(makePhotonRadii(14)), scratchDirectory());
}

TEST(CodecRoundTrip, EyeSegments) {
    expectRoundTrip(std::make_shared<EyeSegments>(makeEyeSegments(15)), scratchDirectory());
}

TEST(CodecRoundTrip, PointIndexOverASubset) {
    expectRoundTrip(std::make_shared<PointIndex>(makePointIndex(16)), scratchDirectory());
}

TEST(CodecRoundTrip, PointIndexOverAllPoints) {
    const std::vector<Vec3> points = randomPoints(17, 100);
    auto index = std::make_shared<PointIndex>();
    index->build(points);
    expectRoundTrip(index, scratchDirectory());
}

TEST(CodecRoundTrip, EmptyPointIndex) { expectRoundTrip(std::make_shared<PointIndex>(), scratchDirectory()); }

TEST(CodecRoundTrip, PhotonBvh) { expectRoundTrip(std::make_shared<PhotonBvh>(makePhotonBvh(18)), scratchDirectory()); }

TEST(CodecRoundTrip, EmptyPhotonBvh) { expectRoundTrip(std::make_shared<PhotonBvh>(), scratchDirectory()); }

TEST(CodecInfo, HeaderListsTypeJobItemsAndColumns) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "photons.fgbuf").string();
    saveBuffer(makeBuffer(std::make_shared<PhotonMap>(makePhotonMap(19, 9))), path, "seed = 3");
    const BufferFileInfo info = readBufferInfo(path);
    EXPECT_EQ(info.type, "PhotonMap");
    EXPECT_EQ(info.jobText, "seed = 3");
    EXPECT_EQ(info.items, 9u);
    const std::vector<std::string> columns = {"photons.position", "photons.incident", "photons.power",
                                              "photons.normal",   "photons.class",    "photons.dudx",
                                              "photons.dvdx"};
    EXPECT_EQ(info.columns, columns);
}

TEST(CodecInfo, EmptyJobText) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "radii.fgbuf").string();
    saveBuffer(makeBuffer(std::make_shared<PhotonRadii>(makePhotonRadii(20))), path, "");
    EXPECT_EQ(readBufferInfo(path).jobText, "");
    EXPECT_EQ(readBufferInfo(path).items, 30u);
}

// --- Refused files -----------------------------------------------------------

TEST(CodecRefuses, WrongTypeNamingFileAndBothTypes) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "photons.fgbuf").string();
    saveBuffer(makeBuffer(std::make_shared<PhotonMap>(makePhotonMap(21))), path, "");
    try {
        loadBuffer(path, "Film", "image");
        FAIL() << "a PhotonMap file loaded as a Film";
    } catch (const InputError& error) {
        EXPECT_EQ(std::string(error.what()), path + ": holds a PhotonMap buffer, but 'image' is a Film");
    }
    EXPECT_EQ(expectRefused(path, "EyeVertices"),
              path + ": holds a PhotonMap buffer, but an EyeVertices buffer is expected");
    // Any type is accepted when none is expected.
    EXPECT_EQ(loadBuffer(path, "").type, "PhotonMap");
}

TEST(CodecRefuses, MissingFile) {
    const std::string path = (scratchDirectory() / "absent.fgbuf").string();
    EXPECT_NE(expectRefused(path).find("cannot open"), std::string::npos);
    EXPECT_THROW(readBufferInfo(path), InputError);
}

TEST(CodecRefuses, Directory) { expectRefused(scratchDirectory().string()); }

TEST(CodecRefuses, EmptyFile) {
    const std::string path = (scratchDirectory() / "empty.fgbuf").string();
    writeBytes(path, "");
    EXPECT_NE(expectRefused(path).find("empty"), std::string::npos);
    EXPECT_THROW(readBufferInfo(path), InputError);
}

TEST(CodecRefuses, NotABufferFile) {
    const std::string path = (scratchDirectory() / "text.fgbuf").string();
    writeBytes(path, "[job]\npipeline = \"pt\"\n");
    EXPECT_EQ(expectRefused(path), path + ": not a fluxgraph buffer file");
}

TEST(CodecRefuses, UnsupportedFormatVersion) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "radii.fgbuf").string();
    saveBuffer(makeBuffer(std::make_shared<PhotonRadii>(makePhotonRadii(22))), path, "");
    std::string bytes = readBytes(path);
    const std::uint32_t future = kBufferFormatVersion + 1;
    std::memcpy(bytes.data() + sizeof kBufferFileMagic, &future, sizeof future);
    writeBytes(path, bytes);
    EXPECT_NE(expectRefused(path).find("version 2 is not supported"), std::string::npos);
    EXPECT_THROW(readBufferInfo(path), InputError);
}

TEST(CodecRefuses, EveryTruncationOfEveryType) {
    const fs::path dir = scratchDirectory();
    for (const auto& [type, make] : everyBuffer()) {
        const std::string whole = (dir / (type + ".fgbuf")).string();
        saveBuffer(make(), whole, "job");
        const std::string bytes = readBytes(whole);
        const std::string cut = (dir / (type + "-cut.fgbuf")).string();
        // Every prefix of the small files; a spread of them for the larger ones.
        const std::size_t step = std::max<std::size_t>(1, bytes.size() / 100);
        for (std::size_t length = 0; length < bytes.size(); length += length < 256 ? 1 : step) {
            writeBytes(cut, bytes.substr(0, length));
            SCOPED_TRACE(type + " cut to " + std::to_string(length) + " of " + std::to_string(bytes.size()) + " bytes");
            expectRefused(cut, type);
        }
        writeBytes(cut, bytes.substr(0, bytes.size() - 1));
        expectRefused(cut, type);
        // One byte too many is refused too.
        writeBytes(cut, bytes + '\0');
        expectRefused(cut, type);
    }
}

TEST(CodecRefuses, RandomBytes) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "random.fgbuf").string();
    Random random(23);
    for (int trial = 0; trial < 200; ++trial) {
        std::string bytes(random.below(600), '\0');
        for (char& c : bytes) c = static_cast<char>(random.below(256));
        // Half of them behind a valid magic and version, to reach the header's lengths.
        if (trial % 2 == 1 && bytes.size() >= 9) {
            std::memcpy(bytes.data(), kBufferFileMagic, sizeof kBufferFileMagic);
            std::memcpy(bytes.data() + sizeof kBufferFileMagic, &kBufferFormatVersion, sizeof kBufferFormatVersion);
        }
        writeBytes(path, bytes);
        SCOPED_TRACE("trial " + std::to_string(trial));
        expectRefused(path);
    }
}

// Header pieces written by hand, for files that lie about their lengths.
class HeaderBuilder {
public:
    HeaderBuilder() {
        bytes_.append(kBufferFileMagic, sizeof kBufferFileMagic);
        u32(kBufferFormatVersion);
    }
    HeaderBuilder& u32(std::uint32_t value) { return raw(&value, sizeof value); }
    HeaderBuilder& u64(std::uint64_t value) { return raw(&value, sizeof value); }
    HeaderBuilder& string(const std::string& text) {
        u32(static_cast<std::uint32_t>(text.size()));
        bytes_ += text;
        return *this;
    }
    HeaderBuilder& raw(const void* data, std::size_t size) {
        bytes_.append(static_cast<const char*>(data), size);
        return *this;
    }
    const std::string& bytes() const { return bytes_; }

private:
    std::string bytes_;
};

TEST(CodecRefuses, AbsurdLengthsInAValidLookingHeader) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "absurd.fgbuf").string();
    const std::string padding(64, '\0');
    const auto refuses = [&](const HeaderBuilder& header, const std::string& what) {
        SCOPED_TRACE(what);
        writeBytes(path, header.bytes() + padding);
        expectRefused(path);
        EXPECT_THROW(readBufferInfo(path), InputError);
    };
    refuses(HeaderBuilder().u32(0xffffffffu), "type name of 4 GiB");
    refuses(HeaderBuilder().u32(40), "type name longer than the file");
    refuses(HeaderBuilder().string("Photon\nMap"), "type name with a line break");
    refuses(HeaderBuilder().string("PhotonMap").u32(0xffffffffu), "4 billion columns");
    refuses(HeaderBuilder().string("PhotonMap").u32(1).u32(0xfffffff0u), "column name of 4 GiB");
    refuses(HeaderBuilder().string("PhotonMap").u32(1).string("photons.position").u32(12).u64(std::uint64_t(1) << 60),
            "column of 2^60 elements");
    refuses(HeaderBuilder().string("PhotonMap").u32(1).string("photons.position").u32(0xffffffffu).u64(0xffffffffu),
            "column whose byte count overflows 32 bits");
    refuses(HeaderBuilder().string("PhotonMap").u32(1).string("photons.position").u32(0).u64(5),
            "column of 0-byte elements");
    refuses(HeaderBuilder().string("PhotonMap").u32(2).string("a").u32(8).u64(4).string("b").u32(8).u64(
                ~std::uint64_t(0) / 8),
            "columns whose sizes overflow 64 bits together");
    refuses(HeaderBuilder().string("PhotonMap").u32(0).u64(1).u32(0xffffff00u), "job text of 4 GiB");
}

TEST(CodecRefuses, UnknownType) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "unknown.fgbuf").string();
    writeBytes(path, HeaderBuilder().string("Teapot").u32(0).u64(0).string("").bytes());
    EXPECT_EQ(readBufferInfo(path).type, "Teapot");
    EXPECT_NE(expectRefused(path).find("holds a Teapot buffer, which this build cannot read"), std::string::npos);
}

TEST(CodecRefuses, ColumnsThatDoNotMatchTheDeclaration) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "radii.fgbuf").string();
    const float radii[2] = {0.5f, 0.25f};
    // A PhotonRadii file whose one column has the wrong name, then the wrong element size.
    writeBytes(path, HeaderBuilder().string("PhotonRadii").u32(1).string("radii.diameter").u32(4).u64(2).u64(2)
                         .string("").u32(16).raw(radii, sizeof radii).bytes() +
                         std::string(4, '\0'));
    EXPECT_NE(expectRefused(path).find("'radii.diameter'"), std::string::npos);
    std::string bytes = HeaderBuilder().string("PhotonRadii").u32(1).string("radii.radius").u32(8).u64(1).u64(1)
                            .string("").u32(16).bytes();
    bytes += std::string(4, '\0') + std::string(reinterpret_cast<const char*>(radii), sizeof radii);
    writeBytes(path, bytes);
    EXPECT_NE(expectRefused(path).find("8-byte elements"), std::string::npos);
}

TEST(CodecRefuses, SoaColumnsOfDifferentLengths) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "photons.fgbuf").string();
    saveBuffer(makeBuffer(std::make_shared<PhotonMap>(makePhotonMap(24, 4))), path, "");
    std::string bytes = readBytes(path);
    // The second column's count: magic, version, type, count, then "photons.position" 12 4.
    const std::size_t offset = sizeof kBufferFileMagic + 4 + (4 + 9) + 4 + (4 + 16 + 4 + 8) + (4 + 16 + 4);
    std::uint64_t count;
    std::memcpy(&count, bytes.data() + offset, sizeof count);
    ASSERT_EQ(count, 4u);
    count = 3;
    std::memcpy(bytes.data() + offset, &count, sizeof count);
    // Its last element goes too, so that the file has the size its header
    // now gives and it is the columns' disagreement that is refused. The
    // payload: emitted, collapsed footprints, the differentials flag, then
    // the columns in header order.
    const CodecReader original(path);
    const std::vector<CodecColumn>& columns = original.columns();
    ASSERT_EQ(columns[1].name, "photons.incident");
    const std::size_t payload = bytes.size() - original.remaining();
    const std::size_t lastIncident = payload + 8 + 8 + 1 + columns[0].count * columns[0].elementSize +
                                     3 * columns[1].elementSize;
    bytes.erase(lastIncident, columns[1].elementSize);
    writeBytes(path, bytes);
    EXPECT_NE(expectRefused(path).find("photons.incident"), std::string::npos);
}

// Arrays that are complete but do not form a tree a query can walk.
TEST(CodecRefuses, CorruptPointIndex) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "index.fgbuf").string();
    auto index = std::make_shared<PointIndex>(makePointIndex(25));
    saveBuffer(makeBuffer(index), path, "");
    std::string bytes = readBytes(path);
    // The last two columns are the permutation and the splits.
    const std::size_t splitBytes = index->tree().splits().size_bytes();
    const std::size_t permutationAt = bytes.size() - splitBytes - index->tree().permutation().size_bytes();
    std::string duplicate = bytes;
    std::memcpy(duplicate.data() + permutationAt, duplicate.data() + permutationAt + 4, 4);
    writeBytes(path, duplicate);
    EXPECT_NE(expectRefused(path).find("permutation"), std::string::npos);
    std::string badAxis = bytes;
    const std::uint32_t axis = 7;
    std::memcpy(badAxis.data() + bytes.size() - splitBytes + 4, &axis, 4);
    writeBytes(path, badAxis);
    EXPECT_NE(expectRefused(path).find("axis"), std::string::npos);
}

TEST(CodecRefuses, CorruptPhotonBvh) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "bvh.fgbuf").string();
    auto bvh = std::make_shared<PhotonBvh>(makePhotonBvh(26));
    ASSERT_EQ(bvh->nodes().column<BvhNodeCount>()[0], 0u);  // the root is an inner node
    saveBuffer(makeBuffer(bvh), path, "");
    const std::string bytes = readBytes(path);
    // Columns at the end: nodes.lo, .hi, .link, .count, then the sphere columns.
    const std::size_t sphereBytes = bvh->spheres().size() * (4 * sizeof(float) + sizeof(std::uint32_t));
    const std::size_t nodes = bvh->nodeCount();
    const std::size_t linkAt = bytes.size() - sphereBytes - 2 * nodes * sizeof(std::uint32_t);
    const std::size_t countAt = linkAt + nodes * sizeof(std::uint32_t);
    const auto refusedWith = [&](std::size_t at, std::uint32_t value) {
        std::string corrupt = bytes;
        std::memcpy(corrupt.data() + at, &value, sizeof value);
        writeBytes(path, corrupt);
        return expectRefused(path, "PhotonBvh");
    };
    EXPECT_NE(refusedWith(linkAt, 0xffffffffu).find("children"), std::string::npos);
    EXPECT_NE(refusedWith(linkAt, 0u).find("children"), std::string::npos);  // a cycle back to the root
    EXPECT_NE(refusedWith(countAt, 65u).find("leaf"), std::string::npos);
    // The depth, the first payload scalar, right after the empty job text.
    const std::size_t depthAt =
        bytes.size() - sphereBytes - nodes * (2 * sizeof(Vec3) + 2 * sizeof(std::uint32_t)) - 4;
    EXPECT_NE(refusedWith(depthAt, bvh->depth() + 1).find("depth"), std::string::npos);
}

TEST(CodecRefuses, CorruptFilm) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "film.fgbuf").string();
    auto film = std::make_shared<Film>(makeFilm(27));
    saveBuffer(makeBuffer(film), path, "");
    std::string bytes = readBytes(path);
    // The header is followed by width and height: make the image claim 2^31 - 1 rows.
    const std::size_t payloadAt = bytes.size() - (film->pixelCount() * (2 * sizeof(Rgb) + sizeof(float)) +
                                                  4 * 5 + 1 + 4 + 2 * (4 + 7 + film->pixelCount() * sizeof(float)));
    std::int32_t width;
    std::memcpy(&width, bytes.data() + payloadAt, sizeof width);
    ASSERT_EQ(width, 7);
    const std::int32_t rows = std::numeric_limits<std::int32_t>::max();
    std::memcpy(bytes.data() + payloadAt + 4, &rows, sizeof rows);
    writeBytes(path, bytes);
    EXPECT_NE(expectRefused(path).find("Film"), std::string::npos);
}

// Any single damaged byte of a small file of each type: loaded or refused
// with an InputError, never a crash or another exception.
TEST(CodecRefuses, EverySingleByteDamageIsHandled) {
    const fs::path dir = scratchDirectory();
    for (const auto& [type, make] : everyBuffer()) {
        const std::string whole = (dir / (type + ".fgbuf")).string();
        saveBuffer(make(), whole, "job");
        const std::string bytes = readBytes(whole);
        const std::string damaged = (dir / (type + "-damaged.fgbuf")).string();
        const std::size_t step = std::max<std::size_t>(1, bytes.size() / 200);
        for (std::size_t at = 0; at < bytes.size(); at += at < 256 ? 1 : step) {
            std::string copy = bytes;
            copy[at] = static_cast<char>(copy[at] ^ 0xff);
            writeBytes(damaged, copy);
            try {
                loadBuffer(damaged, "");
            } catch (const InputError&) {
            } catch (const std::exception& error) {
                ADD_FAILURE() << type << " damaged at byte " << at << ": " << error.what();
            }
        }
    }
}

// --- Saving ------------------------------------------------------------------

TEST(CodecSave, FailsWithoutLeavingFiles) {
    const fs::path dir = scratchDirectory();
    const BufferHandle photons = makeBuffer(std::make_shared<PhotonMap>(makePhotonMap(28)));
    EXPECT_THROW(saveBuffer(photons, (dir / "missing" / "photons.fgbuf").string(), ""), InputError);

    BufferHandle streamed;
    streamed.type = "PhotonMap";
    EXPECT_THROW(saveBuffer(streamed, (dir / "streamed.fgbuf").string(), ""), InputError);

    BufferHandle unknown = photons;
    unknown.type = "Teapot";
    EXPECT_THROW(saveBuffer(unknown, (dir / "teapot.fgbuf").string(), ""), InputError);
    EXPECT_TRUE(fs::is_empty(dir));
}

TEST(CodecSave, ReplacesAnExistingFile) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "photons.fgbuf").string();
    saveBuffer(makeBuffer(std::make_shared<PhotonMap>(makePhotonMap(29, 5))), path, "first");
    saveBuffer(makeBuffer(std::make_shared<PhotonMap>(makePhotonMap(30, 8))), path, "second");
    EXPECT_EQ(readBufferInfo(path).items, 8u);
    EXPECT_EQ(readBufferInfo(path).jobText, "second");
    EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);
}

// A codec registered for a new type is used by saveBuffer and loadBuffer.
struct CodecTestCounter {
    std::uint64_t value = 0;
    std::vector<std::int16_t> history;
    std::size_t bytes() const { return history.capacity() * sizeof(std::int16_t); }
};

}  // namespace

template <>
struct BufferTypeName<CodecTestCounter> {
    static constexpr const char* value = "CodecTestCounter";
};

namespace {

TEST(CodecRegistry, RegisteredCodecIsUsed) {
    BufferCodec codec;
    codec.type = "CodecTestCounter";
    codec.write = [](const void* buffer, CodecWriter& writer) {
        const auto& counter = *static_cast<const CodecTestCounter*>(buffer);
        writer.setItemCount(counter.history.size());
        writer.write(counter.value);
        writer.writeString("note");
        writer.writeVector("history", counter.history);
    };
    codec.read = [](CodecReader& reader) {
        CodecTestCounter counter;
        counter.value = reader.read<std::uint64_t>();
        if (reader.readString() != "note") reader.fail("lost the note");
        counter.history = reader.readVector<std::int16_t>("history");
        return makeBufferHandle(std::move(counter));
    };
    registerCodec(codec);
    ASSERT_NE(findCodec("CodecTestCounter"), nullptr);

    const std::string path = (scratchDirectory() / "counter.fgbuf").string();
    auto counter = std::make_shared<CodecTestCounter>();
    counter->value = 42;
    counter->history = {-3, 5, 7};
    saveBuffer(makeBuffer(counter), path, "");
    const BufferHandle loaded = loadBuffer(path, "CodecTestCounter");
    EXPECT_EQ(test::bufferAs<CodecTestCounter>(loaded).value, 42u);
    EXPECT_EQ(test::bufferAs<CodecTestCounter>(loaded).history, counter->history);
    EXPECT_EQ(readBufferInfo(path).columns, std::vector<std::string>{"history"});
}


// checkBufferFile (what validate runs on imported files) refuses a codec
// version as loadBuffer does, with the same line, without running the codec's
// read; loadBuffer runs the version check and then the read.
TEST(CodecRegistry, CheckingAFileRunsTheVersionCheckButNotTheRead) {
    auto reads = std::make_shared<int>(0);
    BufferCodec codec;
    codec.type = "CodecTestCounter";
    codec.write = [](const void* buffer, CodecWriter& writer) {
        const auto& counter = *static_cast<const CodecTestCounter*>(buffer);
        writer.setItemCount(counter.history.size());
        writer.write<std::uint32_t>(7);
        writer.write(counter.value);
        writer.writeVector("history", counter.history);
    };
    codec.checkVersion = codecVersionCheck(7, "a counter");
    codec.read = [reads](CodecReader& reader) {
        ++*reads;
        CodecTestCounter counter;
        counter.value = reader.read<std::uint64_t>();
        counter.history = reader.readVector<std::int16_t>("history");
        return makeBufferHandle(std::move(counter));
    };
    registerCodec(codec);

    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "versioned.fgbuf").string();
    auto counter = std::make_shared<CodecTestCounter>();
    counter->value = 9;
    counter->history = {1, 2, 3};
    saveBuffer(makeBuffer(counter), path, "");
    EXPECT_EQ(test::inputErrorOf([&] { checkBufferFile(path, "CodecTestCounter", "counter"); }), "");
    EXPECT_EQ(*reads, 0);
    EXPECT_EQ(test::bufferAs<CodecTestCounter>(loadBuffer(path, "CodecTestCounter")).value, 9u);
    EXPECT_EQ(*reads, 1);

    // The payload ends with the version, the value and the history.
    std::string bytes = readBytes(path);
    const std::size_t version = bytes.size() - sizeof(std::int16_t) * 3 - sizeof(std::uint64_t) - sizeof(std::uint32_t);
    ASSERT_EQ(bytes[version], '\x07');
    bytes[version] = '\x08';
    const std::string other = (dir / "version8.fgbuf").string();
    writeBytes(other, bytes);
    const std::string checked = test::inputErrorOf([&] { checkBufferFile(other, "CodecTestCounter", "counter"); });
    EXPECT_EQ(checked, other + ": a counter of codec version 8 (this build reads version 7)");
    EXPECT_EQ(test::inputErrorOf([&] { loadBuffer(other, "CodecTestCounter", "counter"); }), checked);
    EXPECT_EQ(*reads, 1);

    // The type is checked first, with loadBuffer's line too.
    const std::string wrongType = test::inputErrorOf([&] { checkBufferFile(other, "Film", "image"); });
    EXPECT_NE(wrongType.find("'image' is a Film"), std::string::npos) << wrongType;
    EXPECT_EQ(test::inputErrorOf([&] { loadBuffer(other, "Film", "image"); }), wrongType);
}

// checkBufferFile refuses a file cut short by one byte or by half, or one
// byte too long, without reading its arrays (the header's columns and the
// codec's scalars give the payload's size), with loadBuffer's line; the file
// as saved passes.
TEST(CodecRefuses, CheckingAFileRefusesItsWrongSizes) {
    const fs::path dir = scratchDirectory();
    for (const auto& [typeName, make] : everyBuffer()) {
        const std::string type = typeName;  // a variable, not a binding: the lambdas below capture it
        const std::string whole = (dir / (type + ".fgbuf")).string();
        saveBuffer(make(), whole, "job");
        EXPECT_EQ(test::inputErrorOf([&] { checkBufferFile(whole, type); }), "") << type;
        const std::string bytes = readBytes(whole);
        const std::string bad = (dir / (type + "-bad.fgbuf")).string();
        for (const std::string& copy :
             {bytes.substr(0, bytes.size() - 1), bytes.substr(0, bytes.size() / 2), bytes + '\0'}) {
            writeBytes(bad, copy);
            const std::string checked = test::inputErrorOf([&] { checkBufferFile(bad, type); });
            EXPECT_EQ(checked.rfind(bad + ": ", 0), 0u) << type << ", " << copy.size() << " bytes: " << checked;
            EXPECT_EQ(checked.find('\n'), std::string::npos) << checked;
            EXPECT_EQ(test::inputErrorOf([&] { loadBuffer(bad, type); }), checked) << type;
        }
    }
}

// Cut inside the scalars after the last column, the file's size is all that
// tells: the line says how many bytes the header calls for.
TEST(CodecRefuses, CheckingAFileCutInItsLastScalarsSaysWhatIsMissing) {
    const fs::path dir = scratchDirectory();
    const std::string path = (dir / "film.fgbuf").string();
    auto film = std::make_shared<Film>(makeFilm(3));
    saveBuffer(makeBuffer(film), path, "job");
    const std::string bytes = readBytes(path);
    const std::size_t payload = bytes.size() - CodecReader(path).remaining();
    writeBytes(path, bytes.substr(0, bytes.size() - 1));
    EXPECT_EQ(test::inputErrorOf([&] { checkBufferFile(path, "Film", "image"); }),
              path + ": truncated buffer file: its header's columns need " + std::to_string(bytes.size() - payload) +
                  " bytes after the header, the file has " + std::to_string(bytes.size() - payload - 1));
    writeBytes(path, bytes + "xyz");
    EXPECT_EQ(test::inputErrorOf([&] { checkBufferFile(path, "Film", "image"); }), path + ": 3 bytes after the end of the buffer");
}

TEST(CodecTypes, EveryBuiltinCodecGivesItsPayloadSize) {
    for (const BufferCodec& codec : builtinCodecs()) EXPECT_TRUE(codec.scalarBytes) << codec.type;
}

// A codec whose scalars differ from what its scalarBytes says would write
// files that validate refuses: saving one is an error, and leaves no file.
TEST(CodecSave, ACodecThatWritesOtherThanItsDeclaredSizeLeavesNoFile) {
    BufferCodec codec;
    codec.type = "CodecTestCounter";
    codec.write = [](const void* buffer, CodecWriter& writer) {
        const auto& counter = *static_cast<const CodecTestCounter*>(buffer);
        writer.write(counter.value);
        writer.writeVector("history", counter.history);
    };
    codec.read = [](CodecReader& reader) {
        CodecTestCounter counter;
        counter.value = reader.read<std::uint64_t>();
        counter.history = reader.readVector<std::int16_t>("history");
        return makeBufferHandle(std::move(counter));
    };
    auto counter = std::make_shared<CodecTestCounter>();
    counter->history = {4, 5};
    const fs::path dir = scratchDirectory();
    registerCodec(withScalarBytes(codec, sizeof(std::uint64_t)));
    saveBuffer(makeBuffer(counter), (dir / "right.fgbuf").string(), "");
    EXPECT_EQ(test::inputErrorOf([&] { checkBufferFile((dir / "right.fgbuf").string(), "CodecTestCounter"); }), "");
    registerCodec(withScalarBytes(codec, sizeof(std::uint32_t)));
    EXPECT_THROW(saveBuffer(makeBuffer(counter), (dir / "wrong.fgbuf").string(), ""), std::logic_error);
    EXPECT_FALSE(fs::exists(dir / "wrong.fgbuf"));
    EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);
}

}  // namespace
}  // namespace fg
