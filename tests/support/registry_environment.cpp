// The test program installs the built-in registry as fluxgraph's main does,
// before any test runs, so engine functions that use the installed registry
// (job files naming built-in pipelines, renders) work as in the program.
#include "passes/passes.h"

#include <gtest/gtest.h>

namespace {

class RegistryEnvironment final : public ::testing::Environment {
public:
    void SetUp() override { fg::installRegistry(&fg::builtinRegistry()); }
};

[[maybe_unused]] ::testing::Environment* const registryEnvironment =
    ::testing::AddGlobalTestEnvironment(new RegistryEnvironment);

}  // namespace
