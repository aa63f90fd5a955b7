// Accelerated EM (engine/gmm/em.h, Jakob et al. 2011 Alg. 1 with §5.3's
// sparsity) on a point set from a file, for tests/tools/check_em_sklearn.py,
// which fits the same points from the same initial guess with scikit-learn's
// full EM and compares the mean log-likelihoods.
//
//   fluxgraph_em_points dump PHOTONS.fgbuf OUT.txt
//       writes the positions of a saved VolumePhotonMap, one "x y z" per line
//   fluxgraph_em_points fit POINTS.txt K CELLS_PER_COMPONENT TAU REG_COVAR EPSILON OUT.json
//       builds the statistics tree over the points, takes §5.4's initial guess
//       (the Gaussians of a K-cell cut), runs EM on a K x CELLS_PER_COMPONENT
//       cut as the `em_fit` pass does, and writes the initial and the final
//       mixtures (weights, means, covariances), the iterations and F / n.
//
// REG_COVAR is in the points' own units: the script hands over points scaled to
// the unit box, where the pass's `reg_covar` means the same.
#include "engine/buffers/photon_buffers.h"
#include "engine/core/codec.h"
#include "engine/gmm/em.h"
#include "engine/gmm/em_tree.h"

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

namespace {

int usage() {
    std::cerr << "usage: fluxgraph_em_points dump PHOTONS.fgbuf OUT.txt\n"
                 "       fluxgraph_em_points fit POINTS.txt K CELLS_PER_COMPONENT TAU REG_COVAR EPSILON OUT.json\n";
    return 2;
}

int dumpPhotons(const std::string& bufferPath, const std::string& outPath) {
    const fg::BufferHandle handle = fg::loadBuffer(bufferPath, fg::BufferTypeName<fg::VolumePhotonMap>::value);
    const auto& map = *static_cast<const fg::VolumePhotonMap*>(handle.data.get());
    std::ofstream out(outPath);
    out << std::setprecision(9);
    for (const fg::Vec3& p : map.photons.column<fg::PhotonPosition>()) out << p.x << ' ' << p.y << ' ' << p.z << '\n';
    if (!out) {
        std::cerr << outPath << ": cannot write\n";
        return 2;
    }
    return 0;
}

void writeMixture(std::ostream& out, const std::vector<fg::gmm::EmComponent>& components) {
    out << "[";
    for (std::size_t s = 0; s < components.size(); ++s) {
        const fg::gmm::EmComponent& c = components[s];
        const fg::gmm::Vec3d& mu = c.gaussian.mean;
        const fg::gmm::Sym3& cov = c.gaussian.covariance;
        out << (s ? ",\n  " : "\n  ") << "{\"weight\": " << c.weight << ", \"mean\": [" << mu.x << ", " << mu.y << ", "
            << mu.z << "], \"covariance\": [";
        for (int row = 0; row < 3; ++row)
            out << (row ? ", [" : "[") << cov(row, 0) << ", " << cov(row, 1) << ", " << cov(row, 2) << "]";
        out << "]}";
    }
    out << "]";
}

int fitPoints(const std::string& pointsPath, std::size_t k, std::size_t cellsPerComponent, double tau,
              double regCovar, double epsilon, const std::string& outPath) {
    std::ifstream in(pointsPath);
    if (!in) {
        std::cerr << pointsPath << ": cannot read\n";
        return 2;
    }
    std::vector<fg::Vec3> positions;
    std::string line;
    for (std::size_t lineNumber = 1; std::getline(in, line); ++lineNumber) {
        std::istringstream fields(line);
        fg::Vec3 p;
        if (!(fields >> p.x >> p.y >> p.z)) {
            std::cerr << pointsPath << ":" << lineNumber << ": expected three numbers\n";
            return 2;
        }
        positions.push_back(p);
    }
    const std::vector<fg::Rgb> power(positions.size(), fg::Rgb(1.0f));

    fg::EmTree tree;
    tree.build(positions, power);
    fg::gmm::EmOptions options;
    options.tau = tau;
    options.regCovar = regCovar;
    options.epsilon = epsilon;
    options.maxIterations = 10000;
    std::vector<fg::gmm::EmComponent> components =
        fg::gmm::componentsFromCells(fg::cellsOf(tree, tree.cut(k)), options.regCovar);
    const std::vector<fg::gmm::EmComponent> initial = components;
    const fg::gmm::EmCells cells = fg::cellsOf(tree, tree.cut(k * cellsPerComponent));
    const fg::gmm::EmRun run = fg::gmm::runEm(cells, components, options);

    std::ofstream out(outPath);
    out << std::setprecision(17) << "{\"points\": " << positions.size() << ", \"cells\": " << cells.size()
        << ", \"iterations\": " << run.iterations << ", \"converged\": " << (run.converged ? "true" : "false")
        << ", \"dropped\": " << run.dropped
        << ", \"bound_per_point\": " << (run.bounds.empty() ? 0.0 : run.bounds.back() / cells.totalCount())
        << ",\n\"initial\": ";
    writeMixture(out, initial);
    out << ",\n\"final\": ";
    writeMixture(out, components);
    out << "}\n";
    if (!out) {
        std::cerr << outPath << ": cannot write\n";
        return 2;
    }
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    try {
        const std::vector<std::string> args(argv + 1, argv + argc);
        if (args.size() == 3 && args[0] == "dump") return dumpPhotons(args[1], args[2]);
        if (args.size() == 8 && args[0] == "fit")
            return fitPoints(args[1], std::stoul(args[2]), std::stoul(args[3]), std::stod(args[4]),
                             std::stod(args[5]), std::stod(args[6]), args[7]);
        return usage();
    } catch (const std::exception& error) {
        std::cerr << "fluxgraph_em_points: " << error.what() << "\n";
        return 2;
    }
}
