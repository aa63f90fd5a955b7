// The line an InputError carries, for tests of what bad input is told.
#pragma once

#include "engine/core/error.h"

#include <functional>
#include <string>

namespace fg::test {

// The InputError's line `f` throws, or "" when it throws none.
inline std::string inputErrorOf(const std::function<void()>& f) {
    try {
        f();
    } catch (const InputError& error) {
        return error.what();
    }
    return "";
}

}  // namespace fg::test
