/// @file fuzz_png.cpp
/// @brief libFuzzer harness over fuzz::pngTarget (FuzzTargets.h): any input must be accepted or
/// refused with a SceneError; anything else aborts and libFuzzer keeps the input.
#include "FuzzTargets.h"

#include <cstdio>
#include <cstdlib>

extern "C" int LLVMFuzzerInitialize(int*, char***)
{
    openvdb::initialize();
    return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size)
{
    const std::string why = frostvdb::fuzz::pngTarget(data, size);
    if (!why.empty()) {
        std::fprintf(stderr, "frostvdb fuzz: %s\n", why.c_str());
        std::abort();
    }
    return 0;
}
