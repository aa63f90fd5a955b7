// `fluxgraph compare TEST REF`: error metrics of a render against a reference.
#pragma once

#include <string>

namespace CLI {
class App;
}

namespace fg::cli {

struct CompareOptions {
    std::string testPath;
    std::string referencePath;
    std::string metric = "all";
    std::string heatmapPath;
    std::string crop;  // "x,y,w,h", empty for the whole image
};

// Registers the subcommand on `app`; the parsed values land in `options`.
CLI::App* addCompareSubcommand(CLI::App& app, CompareOptions& options);
// Prints one "name value" line per selected metric and returns the exit code:
// 0, or 2 (one line on stderr) for unreadable or mismatched images and bad options.
int runCompare(const CompareOptions& options);

}  // namespace fg::cli
