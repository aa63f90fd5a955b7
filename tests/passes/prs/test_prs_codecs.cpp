// Codecs of photon ray splatting's buffers (engine/buffers/photon_ray_codecs.cpp):
// photon rays (as traced and as splatted, at 73 bytes a ray), the splat kd-tree and the SH radiance map survive a save and a
// load byte for byte, the loaded tree answers frustum queries with the same
// vertices in the same order, and a tree whose arrays do not fit together is
// refused; so do the radiance cache's records, and records of another codec
// version are refused.
#include "engine/buffers/photon_ray_buffers.h"
#include "engine/buffers/radiance_cache_buffers.h"
#include "engine/core/error.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

namespace fg {
namespace {

namespace fs = std::filesystem;

fs::path scratch() {
    const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
    const fs::path dir = fs::path(FLUXGRAPH_TEST_TMP) / "prs-codecs" / (std::string(info->test_suite_name()) + "." + info->name());
    fs::remove_all(dir);
    fs::create_directories(dir);
    return dir;
}

template <class T>
BufferHandle handleOf(std::shared_ptr<T> data) {
    BufferHandle handle;
    handle.type = BufferTypeName<T>::value;
    handle.bytes = [raw = data.get()] { return raw->bytes(); };
    handle.data = std::move(data);
    return handle;
}

std::string readBytes(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

// Saves, loads, saves again: the two files must be equal. Returns the loaded buffer.
template <class T>
std::shared_ptr<T> roundTrip(std::shared_ptr<T> original, const fs::path& dir) {
    registerBuiltinCodecs();
    const std::string type = BufferTypeName<T>::value;
    const fs::path first = dir / (type + ".fgbuf"), second = dir / (type + "-again.fgbuf");
    saveBuffer(handleOf(original), first.string(), "# test\n");
    const BufferHandle loaded = loadBuffer(first.string(), type, "buffer");
    EXPECT_EQ(loaded.type, type);
    saveBuffer(loaded, second.string(), "# test\n");
    EXPECT_EQ(readBytes(first), readBytes(second)) << type;
    return std::static_pointer_cast<T>(loaded.data);
}

std::vector<Vec3> randomPoints(std::size_t n, std::uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<Vec3> p(n);
    for (Vec3& x : p) x = Vec3(u(rng), u(rng), u(rng));
    return p;
}

std::shared_ptr<SplatIndex> makeIndex(std::size_t n) {
    std::vector<Vec3> positions = randomPoints(n, 5), normals = randomPoints(n, 6);
    for (Vec3& v : normals) v = glm::normalize(v - Vec3(0.5f));
    auto index = std::make_shared<SplatIndex>();
    index->tree.build(positions, normals, {});
    return index;
}

TEST(PrsCodecs, PhotonRaysRoundTrip) {
    auto rays = std::make_shared<PhotonRays>();
    rays->emitted = 77;
    rays->clampDistance = 0.25f;
    rays->countPerClass = {5, 0, 9};
    rays->normalisation = 1.5;
    rays->sceneScale = 0.125;
    rays->hasBandwidths = true;
    rays->rays.resize(14);
    const std::vector<Vec3> p = randomPoints(14, 1);
    for (std::size_t i = 0; i < 14; ++i) {
        rays->rays.column<RayOrigin>()[i] = p[i];
        rays->rays.column<RayLength>()[i] = static_cast<float>(i) + 0.5f;
        rays->rays.column<RayClassColumn>()[i] = static_cast<std::uint8_t>(i % 3);
        rays->rays.column<RayPath>()[i] = i / 2;
    }
    const auto loaded = roundTrip(rays, scratch());
    ASSERT_TRUE(loaded);
    EXPECT_EQ(loaded->emitted, 77u);
    EXPECT_EQ(loaded->countPerClass, rays->countPerClass);
    EXPECT_EQ(loaded->normalisation, 1.5);
    EXPECT_TRUE(loaded->hasBandwidths);
    ASSERT_EQ(loaded->rays.size(), 14u);
    for (std::size_t i = 0; i < 14; ++i) EXPECT_EQ(loaded->rays.column<RayOrigin>()[i], p[i]);
}

// The splat passes' rays: every column survives, and the buffer holds the
// 73 bytes a ray that the README's memory figures count (origin, direction,
// length, power, h_0, dh, class, origin and end normals).
TEST(PrsCodecs, SplatRaysRoundTripAtSeventyThreeBytesARay) {
    constexpr std::size_t kRays = 1000;
    auto rays = std::make_shared<SplatRays>();
    rays->emitted = 500;
    rays->clampDistance = 0.5f;
    rays->countPerClass = {300, 200, 500};
    rays->normalisation = 2.5;
    rays->sceneScale = 0.0625;
    rays->rays.resize(kRays);
    EXPECT_EQ(kSplatRayBytes, 73u);
    EXPECT_EQ(rays->bytes(), kRays * kSplatRayBytes);
    const std::vector<Vec3> p = randomPoints(kRays, 2), d = randomPoints(kRays, 3), nOrigin = randomPoints(kRays, 4),
                            nEnd = randomPoints(kRays, 7);
    SplatRayBuffer& r = rays->rays;
    for (std::size_t i = 0; i < kRays; ++i) {
        r.column<RayOrigin>()[i] = p[i];
        r.column<RayDirection>()[i] = glm::normalize(d[i] - Vec3(0.5f));
        r.column<RayLength>()[i] = 0.25f * static_cast<float>(i) + 0.125f;
        r.column<RayPower>()[i] = Rgb(p[i].x, p[i].y, 1.0f / static_cast<float>(i + 1));
        r.column<RayH0>()[i] = 1e-3f * static_cast<float>(i);
        r.column<RayDh>()[i] = 1e-4f * static_cast<float>(kRays - i);
        r.column<RayClassColumn>()[i] = static_cast<std::uint8_t>(i % PhotonRayClass::Count);
        r.column<RayOriginNormal>()[i] = nOrigin[i];
        r.column<RayEndNormal>()[i] = nEnd[i];
    }
    const auto loaded = roundTrip(rays, scratch());
    ASSERT_TRUE(loaded);
    EXPECT_EQ(loaded->emitted, 500u);
    EXPECT_EQ(loaded->clampDistance, 0.5f);
    EXPECT_EQ(loaded->countPerClass, rays->countPerClass);
    EXPECT_EQ(loaded->normalisation, 2.5);
    EXPECT_EQ(loaded->sceneScale, 0.0625);
    EXPECT_EQ(loaded->bytes(), kRays * kSplatRayBytes);
    const SplatRayBuffer& l = loaded->rays;
    ASSERT_EQ(l.size(), kRays);
    for (std::size_t i = 0; i < kRays; ++i) {
        EXPECT_EQ(l.column<RayOrigin>()[i], r.column<RayOrigin>()[i]);
        EXPECT_EQ(l.column<RayDirection>()[i], r.column<RayDirection>()[i]);
        EXPECT_EQ(l.column<RayLength>()[i], r.column<RayLength>()[i]);
        EXPECT_EQ(l.column<RayPower>()[i], r.column<RayPower>()[i]);
        EXPECT_EQ(l.column<RayH0>()[i], r.column<RayH0>()[i]);
        EXPECT_EQ(l.column<RayDh>()[i], r.column<RayDh>()[i]);
        EXPECT_EQ(l.column<RayClassColumn>()[i], r.column<RayClassColumn>()[i]);
        EXPECT_EQ(l.column<RayOriginNormal>()[i], r.column<RayOriginNormal>()[i]);
        EXPECT_EQ(l.column<RayEndNormal>()[i], r.column<RayEndNormal>()[i]);
    }
}

TEST(PrsCodecs, SplatRaysOfAnUnknownClassAreRefused) {
    auto rays = std::make_shared<SplatRays>();
    rays->rays.resize(3);
    rays->rays.column<RayClassColumn>()[1] = PhotonRayClass::Count;
    registerBuiltinCodecs();
    const fs::path file = scratch() / "bad.fgbuf";
    saveBuffer(handleOf(rays), file.string(), "# test\n");
    EXPECT_THROW(loadBuffer(file.string(), "SplatRays", "splat_rays"), InputError);
}

TEST(PrsCodecs, SplatIndexRoundTripAnswersTheSameQueries) {
    const auto index = makeIndex(3000);
    const auto loaded = roundTrip(index, scratch());
    ASSERT_TRUE(loaded);
    ASSERT_EQ(loaded->tree.size(), index->tree.size());
    std::mt19937 rng(9);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::size_t coneHits = 0;
    for (int q = 0; q < 200; ++q) {
        SplatCone cone;
        cone.origin = Vec3(u(rng), u(rng), u(rng));
        cone.direction = glm::normalize(Vec3(u(rng), u(rng), u(rng)) - Vec3(0.5f));
        cone.h0 = 0.05f * u(rng);
        cone.dh = 0.1f * u(rng);
        cone.tCap = cone.tMax = u(rng);
        std::vector<std::uint32_t> a, b;
        index->tree.forEachCandidate(cone, [&](std::uint32_t s) { a.push_back(index->tree.vertexOf(s)); });
        loaded->tree.forEachCandidate(cone, [&](std::uint32_t s) { b.push_back(loaded->tree.vertexOf(s)); });
        ASSERT_EQ(a, b) << "query " << q;
        // The tight boxes and coordinate columns are rebuilt on loading.
        a.clear();
        b.clear();
        index->tree.forEachVertexInCone(cone, [&](std::uint32_t s) { a.push_back(index->tree.vertexOf(s)); });
        loaded->tree.forEachVertexInCone(cone, [&](std::uint32_t s) { b.push_back(loaded->tree.vertexOf(s)); });
        ASSERT_EQ(a, b) << "cone query " << q;
        coneHits += a.size();
    }
    EXPECT_GT(coneHits, 200u);
}

// The memory estimate counts the four-wide nodes of the cone search (about
// 280 bytes each), which outweigh the 8-byte nodes and were left out.
TEST(PrsCodecs, SplatIndexBytesCountTheWideNodes) {
    const auto index = makeIndex(5000);
    const SplatKdTree& tree = index->tree;
    ASSERT_GT(tree.wideNodeCount(), 0u);
    const std::size_t binaryAndVertices =
        tree.nodes().size() * sizeof(SplatKdNode) + tree.size() * (2 * sizeof(Vec3) + sizeof(std::uint32_t));
    EXPECT_GE(index->bytes(), binaryAndVertices + tree.wideNodeCount() * SplatKdTree::wideNodeBytes());
    EXPECT_GE(SplatKdTree::wideNodeBytes(), 256u);
    // Restored from its file the tree derives the same arrays again.
    const auto loaded = roundTrip(index, scratch());
    ASSERT_TRUE(loaded);
    EXPECT_EQ(loaded->bytes(), index->bytes());
}

TEST(PrsCodecs, EmptySplatIndexAndRadianceMapRoundTrip) {
    EXPECT_TRUE(roundTrip(std::make_shared<SplatIndex>(), scratch()));
    auto map = std::make_shared<RadianceMap>();
    map->vertices.resize(3);
    map->vertices.column<MapVertex>()[2] = 41;
    map->vertices.column<MapSh7>()[1] = Rgb(1.0f, 2.0f, 3.0f);
    const auto loaded = roundTrip(map, scratch());
    ASSERT_TRUE(loaded);
    EXPECT_EQ(loaded->vertices.column<MapVertex>()[2], 41u);
    EXPECT_EQ(loaded->vertices.column<MapSh7>()[1], Rgb(1.0f, 2.0f, 3.0f));
}

TEST(PrsCodecs, SplatTreeWhoseArraysDoNotFitIsRefused) {
    const auto index = makeIndex(200);
    const SplatKdTree& t = index->tree;
    const auto restore = [&](std::vector<SplatKdNode> nodes, std::vector<std::uint32_t> ids) {
        return SplatKdTree::restore(t.options(), t.boundsMin(), t.boundsMax(), std::move(nodes), std::move(ids),
                                    {t.slotPositions().begin(), t.slotPositions().end()},
                                    {t.slotNormals().begin(), t.slotNormals().end()});
    };
    const std::vector<SplatKdNode> nodes(t.nodes().begin(), t.nodes().end());
    const std::vector<std::uint32_t> ids(t.ids().begin(), t.ids().end());
    EXPECT_NO_THROW(restore(nodes, ids));
    std::vector<std::uint32_t> repeated = ids;
    repeated[1] = repeated[0];
    EXPECT_THROW(restore(nodes, repeated), std::invalid_argument);
    for (std::size_t i = 0; i < nodes.size(); ++i) {
        if (nodes[i].kind() != SplatKdNode::Interior) continue;
        std::vector<SplatKdNode> broken = nodes;
        broken[i].b = (broken[i].b & 15u) | (0x0fffffffu << 4);  // right child far outside
        EXPECT_THROW(restore(broken, ids), std::invalid_argument);
        break;
    }
    for (std::size_t i = 0; i < nodes.size(); ++i) {
        if (nodes[i].kind() != SplatKdNode::Leaf) continue;
        std::vector<SplatKdNode> broken = nodes;
        broken[i].b += 4u;  // one vertex more than it has
        EXPECT_THROW(restore(broken, ids), std::invalid_argument);
        break;
    }
}

TEST(PrsCodecs, CacheRecordsRoundTrip) {
    auto cache = std::make_shared<CacheRecords>();
    cache->error = 0.7f;
    cache->records.resize(3);
    for (std::size_t k = 0; k < 3; ++k) {
        CacheCoefficientArray c{};
        for (std::size_t i = 0; i < c.size(); ++i) c[i] = Rgb(static_cast<float>(k + i), 0.5f, -0.25f * static_cast<float>(i));
        cache->records.set(k, CacheRecordBuffer::Record(Vec3(static_cast<float>(k), 1.0f, 2.0f), Vec3(0.0f, 0.0f, 1.0f),
                                                        0.1f + static_cast<float>(k), static_cast<std::uint32_t>(7 * k), c));
    }
    const fs::path dir = scratch();
    const auto loaded = roundTrip(cache, dir);
    EXPECT_EQ(loaded->error, 0.7f);
    ASSERT_EQ(loaded->records.size(), 3u);
    EXPECT_EQ(loaded->records.column<CachePixel>()[2], 14u);
    EXPECT_EQ(loaded->records.column<CacheCoefficients>()[1][15], cache->records.column<CacheCoefficients>()[1][15]);

    // The codec version is the first scalar of the payload, right after the
    // header; a file claiming version 2 must be refused, not misread.
    const fs::path file = dir / "CacheRecords.fgbuf";
    std::string bytes = readBytes(file);
    const std::string header = "test\n";
    const std::size_t payload = bytes.find(header);
    ASSERT_NE(payload, std::string::npos);
    const std::size_t version = payload + header.size();
    ASSERT_EQ(bytes[version], '\x01');
    bytes[version] = '\x02';
    std::ofstream(file, std::ios::binary | std::ios::trunc) << bytes;
    EXPECT_THROW(loadBuffer(file.string(), "CacheRecords", "buffer"), InputError);
}

}  // namespace
}  // namespace fg
