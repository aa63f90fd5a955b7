// Scene geometry in world space: triangle meshes (from OBJ/PLY or generated
// rectangles, disks and cubes) and analytic spheres. Spheres stay analytic all
// the way into Embree (user geometry): refraction through a glass sphere is the
// heart of the caustic scenes, and a tessellated sphere's facets would imprint
// themselves on every caustic it focuses.
#pragma once

#include "engine/core/math.h"

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

namespace fg {

// A named value per vertex or per triangle (Mitsuba's mesh attributes, read by
// its mesh_attribute texture): "vertex_*" names are per vertex, "face_*" names
// per triangle (a polygon's value is repeated on each of its triangles).
struct MeshAttribute {
    std::string name;
    int channels = 1;           // 1 or 3
    std::vector<float> values;  // channels per vertex or per triangle, interleaved

    bool perVertex() const { return name.starts_with("vertex_"); }
};

struct TriangleMesh {
    std::vector<Vec3> positions;
    std::vector<Vec3> normals;  // per vertex, optional (empty: flat shading)
    std::vector<Vec2> uvs;      // per vertex, optional
    std::vector<std::uint32_t> indices;  // three per triangle
    std::vector<MeshAttribute> attributes;  // vertex colours are "vertex_color"

    std::size_t triangleCount() const { return indices.size() / 3; }
    const MeshAttribute* attribute(std::string_view name) const {
        for (const MeshAttribute& a : attributes)
            if (a.name == name) return &a;
        return nullptr;
    }
    void transform(const Mat4& toWorld);
    void flipNormals();  // reverses winding and per-vertex normals
    float area() const;
};

struct Sphere {
    Vec3 center{0.0f};
    float radius = 1.0f;
    // Rotation from world to the sphere's object frame: it only turns the (u, v)
    // parametrisation (poles on the object's z axis), the geometry is symmetric.
    Mat3 worldToObject{1.0f};
};

// A mesh shared by several shapes (Mitsuba's shape groups and instances): its
// object-space data once, and where this shape puts it. Ray queries trace it as
// an Embree instance of one shared acceleration structure.
struct MeshInstance {
    std::shared_ptr<const TriangleMesh> mesh;
    Mat4 toWorld{1.0f};

    Vec3 point(const Vec3& p) const { return Vec3(toWorld * Vec4(p, 1.0f)); }
    // A transformed copy, for code that needs world-space triangles once (area lights).
    TriangleMesh worldMesh() const;
    float area() const;
};

// Generators in object space, as Mitsuba defines them: rectangle [-1,1]^2 at z=0
// facing +z; disk of radius 1 at z=0 facing +z with uv = (r, phi / 2 pi); cube
// [-1,1]^3 facing outwards.
TriangleMesh makeRectangleMesh();
TriangleMesh makeDiskMesh(int segments = 128);
TriangleMesh makeCubeMesh();
// Mitsuba's cylinder: an open tube of radius 1 around the z axis from z = 0 to
// z = 1, facing outwards, uv = (phi / 2 pi, z); `segments` flat facets with
// radial (smooth) vertex normals. A tessellated tube keeps every mesh path
// (area sampling, instancing, transforms) for a shape that is rarely refractive.
TriangleMesh makeCylinderMesh(int segments = 256);
// Maps that unit tube onto the tube of `radius` from p0 to p1 (p0 != p1).
Mat4 cylinderPlacement(const Vec3& p0, const Vec3& p1, float radius);
// Loads a Wavefront OBJ (all groups merged); throws InputError naming file and problem.
TriangleMesh loadObjMesh(const std::string& path);
// Loads a Stanford PLY (ASCII or binary, either byte order; polygons are
// triangulated, point and line elements rejected). Texture coordinates are
// returned as stored in the file; throws InputError naming file and problem.
TriangleMesh loadPlyMesh(const std::string& path);

// Loads shape `shapeIndex` of a Mitsuba .serialized file (format versions 3
// and 4, zlib-compressed); throws InputError naming file and problem.
TriangleMesh loadSerializedMesh(const std::string& path, int shapeIndex = 0);

struct ShapeSample {
    Vec3 p{0.0f};
    Vec3 n{0.0f};
    Vec2 uv{0.0f};
    float pdfArea = 0.0f;
};

struct Shape {
    std::string name;
    std::variant<TriangleMesh, Sphere, MeshInstance> geometry;
    int bsdf = -1;            // index into Scene::bsdfs
    int interiorMedium = -1;  // index into Scene::media, -1 = none
    int exteriorMedium = -1;
    int areaLight = -1;       // index into Scene::lights, -1 = not an emitter
    bool flipNormals = false; // spheres: normals point inwards

    bool isSphere() const { return std::holds_alternative<Sphere>(geometry); }
    // The shape's triangles in world space: the mesh itself, or an instance's transformed copy.
    TriangleMesh worldMesh() const;
    float area() const;
};

}  // namespace fg
