#pragma once
/// @file Error.h
/// @brief Moved to base/Error.h (below core and io, issue 26); this header keeps existing includes working.
#include <frostvdb/base/Error.h>
