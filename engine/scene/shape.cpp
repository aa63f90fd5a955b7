#include "engine/scene/shape.h"

#include <cmath>

namespace fg {

void TriangleMesh::transform(const Mat4& toWorld) {
    for (Vec3& p : positions) p = Vec3(toWorld * Vec4(p, 1.0f));
    // Normals transform with the inverse transpose; a mirroring transform flips
    // the winding, which is undone so that geometric and shading normals agree.
    const Mat3 normalMatrix = glm::transpose(glm::inverse(Mat3(toWorld)));
    for (Vec3& n : normals) n = glm::normalize(normalMatrix * n);
    if (glm::determinant(Mat3(toWorld)) < 0.0f) {
        for (std::size_t t = 0; t + 2 < indices.size(); t += 3) std::swap(indices[t + 1], indices[t + 2]);
    }
}

void TriangleMesh::flipNormals() {
    for (std::size_t t = 0; t + 2 < indices.size(); t += 3) std::swap(indices[t + 1], indices[t + 2]);
    for (Vec3& n : normals) n = -n;
}

float TriangleMesh::area() const {
    double sum = 0.0;
    for (std::size_t t = 0; t + 2 < indices.size(); t += 3) {
        const Vec3& a = positions[indices[t]];
        const Vec3& b = positions[indices[t + 1]];
        const Vec3& c = positions[indices[t + 2]];
        sum += 0.5 * glm::length(glm::cross(b - a, c - a));
    }
    return static_cast<float>(sum);
}

float Shape::area() const {
    if (const auto* s = std::get_if<Sphere>(&geometry)) return 4.0f * kPi * s->radius * s->radius;
    if (const auto* instance = std::get_if<MeshInstance>(&geometry)) return instance->area();
    return std::get<TriangleMesh>(geometry).area();
}

TriangleMesh Shape::worldMesh() const {
    if (const auto* instance = std::get_if<MeshInstance>(&geometry)) return instance->worldMesh();
    return std::get<TriangleMesh>(geometry);
}

TriangleMesh MeshInstance::worldMesh() const {
    TriangleMesh copy = *mesh;
    copy.transform(toWorld);
    return copy;
}

float MeshInstance::area() const {
    double sum = 0.0;
    const std::vector<std::uint32_t>& indices = mesh->indices;
    for (std::size_t t = 0; t + 2 < indices.size(); t += 3) {
        const Vec3 a = point(mesh->positions[indices[t]]);
        const Vec3 b = point(mesh->positions[indices[t + 1]]);
        const Vec3 c = point(mesh->positions[indices[t + 2]]);
        sum += 0.5 * glm::length(glm::cross(b - a, c - a));
    }
    return static_cast<float>(sum);
}

TriangleMesh makeRectangleMesh() {
    TriangleMesh m;
    m.positions = {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}};
    m.normals = {{0, 0, 1}, {0, 0, 1}, {0, 0, 1}, {0, 0, 1}};
    m.uvs = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    m.indices = {0, 1, 2, 0, 2, 3};
    return m;
}

TriangleMesh makeDiskMesh(int segments) {
    TriangleMesh m;
    // Mitsuba's disk parametrisation is polar, uv = (r, phi / 2 pi): each fan
    // triangle gets corners of its own, so that v does not wrap at the seam and
    // the centre takes the angle of the triangle's middle.
    for (int i = 0; i < segments; ++i) {
        const float v0 = static_cast<float>(i) / static_cast<float>(segments);
        const float v1 = static_cast<float>(i + 1) / static_cast<float>(segments);
        const Vec3 a(std::cos(2.0f * kPi * v0), std::sin(2.0f * kPi * v0), 0.0f);
        const Vec3 b = i + 1 == segments ? Vec3(1.0f, 0.0f, 0.0f) : Vec3(std::cos(2.0f * kPi * v1), std::sin(2.0f * kPi * v1), 0.0f);
        const auto base = static_cast<std::uint32_t>(m.positions.size());
        m.positions.insert(m.positions.end(), {Vec3(0.0f), a, b});
        m.normals.insert(m.normals.end(), {Vec3(0, 0, 1), Vec3(0, 0, 1), Vec3(0, 0, 1)});
        m.uvs.insert(m.uvs.end(), {Vec2(0.0f, 0.5f * (v0 + v1)), Vec2(1.0f, v0), Vec2(1.0f, v1)});
        m.indices.insert(m.indices.end(), {base, base + 1, base + 2});
    }
    return m;
}

TriangleMesh makeCubeMesh() {
    TriangleMesh m;
    // Six faces, each with its own four vertices so normals stay flat.
    const Vec3 normals[6] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    for (const Vec3& n : normals) {
        const Frame f(n);
        const auto base = static_cast<std::uint32_t>(m.positions.size());
        const Vec2 corners[4] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
        for (const Vec2& c : corners) {
            m.positions.push_back(n + f.s * c.x + f.t * c.y);
            m.normals.push_back(n);
            m.uvs.push_back(0.5f * (c + Vec2(1.0f)));
        }
        // Frame(n) is right-handed (s x t = n), so this winding faces outwards.
        m.indices.insert(m.indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
    }
    return m;
}

TriangleMesh makeCylinderMesh(int segments) {
    TriangleMesh m;
    // Two rings with a duplicated seam column, so u runs from 0 to 1 without wrapping.
    for (int i = 0; i <= segments; ++i) {
        const float u = static_cast<float>(i) / static_cast<float>(segments);
        const float phi = 2.0f * kPi * u;
        const Vec3 radial(std::cos(phi), std::sin(phi), 0.0f);
        for (float z : {0.0f, 1.0f}) {
            m.positions.push_back(radial + Vec3(0.0f, 0.0f, z));
            m.normals.push_back(radial);
            m.uvs.push_back({u, z});
        }
    }
    for (int i = 0; i < segments; ++i) {
        const auto bottom = static_cast<std::uint32_t>(2 * i), top = bottom + 1;
        const std::uint32_t nextBottom = bottom + 2, nextTop = bottom + 3;
        // Counter-clockwise seen from outside: (phi, z) increase along s x t = outward.
        m.indices.insert(m.indices.end(), {bottom, nextBottom, nextTop, bottom, nextTop, top});
    }
    return m;
}

Mat4 cylinderPlacement(const Vec3& p0, const Vec3& p1, float radius) {
    const Vec3 axis = p1 - p0;
    const Frame frame(glm::normalize(axis));
    Mat4 m(1.0f);
    m[0] = Vec4(radius * frame.s, 0.0f);
    m[1] = Vec4(radius * frame.t, 0.0f);
    m[2] = Vec4(axis, 0.0f);
    m[3] = Vec4(p0, 1.0f);
    return m;
}

}  // namespace fg
