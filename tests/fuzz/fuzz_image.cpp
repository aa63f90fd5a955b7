// libFuzzer target: see tests/fuzz/fuzz_entry.h and the README's "Fuzzing".
#include "tests/fuzz/fuzz_entry.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    fg::fuzz::fuzzImage({data, size});
    return 0;
}
