// Stanford PLY meshes (Turk 1994; ASCII, binary little- and big-endian)
// through the Open Asset Import Library. The file's own header is checked
// first so that Assimp, which guesses formats, only ever sees PLY data.
// Assimp only parses and validates (indices in range): its other
// post-processing steps assert, and abort the program, on legal but
// degenerate input such as an empty face. Polygons are therefore
// fan-triangulated here (as convex, like Mitsuba's loader does with quads)
// and faces with fewer than three corners are errors. Normals and texture
// coordinates are kept only when every vertex has them.
#include "engine/core/error.h"
#include "engine/scene/shape.h"

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <filesystem>
#include <fstream>
#include <iterator>

namespace fg {

TriangleMesh loadPlyMesh(const std::string& path) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec)) throw InputError(path, 0, "PLY file not found");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(path, 0, "cannot open PLY file");
    const std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (in.bad()) throw InputError(path, 0, "cannot read PLY file");
    if (data.size() < 4 || data.compare(0, 3, "ply") != 0 || (data[3] != '\n' && data[3] != '\r')) {
        throw InputError(path, 0, "not a PLY file (it must start with the line 'ply')");
    }

    Assimp::Importer importer;
    const unsigned flags = aiProcess_ValidateDataStructure;
    const aiScene* scene = importer.ReadFileFromMemory(data.data(), data.size(), flags, "ply");
    if (!scene) throw InputError(path, 0, std::string("cannot parse PLY file: ") + importer.GetErrorString());
    if (scene->mNumMeshes == 0) throw InputError(path, 0, "PLY file contains no faces");

    bool allNormals = true, allUvs = true;
    for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
        const aiMesh* mesh = scene->mMeshes[m];
        allNormals = allNormals && mesh->HasNormals();
        allUvs = allUvs && mesh->HasTextureCoords(0);
    }

    TriangleMesh result;
    for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
        const aiMesh* mesh = scene->mMeshes[m];
        const auto base = static_cast<std::uint32_t>(result.positions.size());
        for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
            const aiVector3D& p = mesh->mVertices[v];
            result.positions.emplace_back(p.x, p.y, p.z);
            if (allNormals) {
                const aiVector3D& n = mesh->mNormals[v];
                const Vec3 normal(n.x, n.y, n.z);
                const float length = glm::length(normal);
                result.normals.push_back(length > 0.0f ? normal / length : normal);
            }
            if (allUvs) result.uvs.emplace_back(mesh->mTextureCoords[0][v].x, mesh->mTextureCoords[0][v].y);
        }
        for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
            const aiFace& face = mesh->mFaces[f];
            if (face.mNumIndices < 3) {
                throw InputError(path, 0, "face " + std::to_string(f) + " has " + std::to_string(face.mNumIndices) +
                                              " corners; only polygon meshes are supported");
            }
            for (unsigned c = 0; c < face.mNumIndices; ++c) {
                if (face.mIndices[c] >= mesh->mNumVertices) throw InputError(path, 0, "face refers to a vertex that does not exist");
            }
            for (unsigned c = 1; c + 1 < face.mNumIndices; ++c) {
                result.indices.push_back(base + face.mIndices[0]);
                result.indices.push_back(base + face.mIndices[c]);
                result.indices.push_back(base + face.mIndices[c + 1]);
            }
        }
    }
    if (result.indices.empty()) throw InputError(path, 0, "PLY file contains no faces");
    for (const Vec3& p : result.positions) {
        if (!isFinite(p)) throw InputError(path, 0, "PLY file contains a vertex position that is not a finite number");
    }
    return result;
}

}  // namespace fg
