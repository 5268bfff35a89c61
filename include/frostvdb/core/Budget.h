#pragma once
/// @file Budget.h
/// @brief Moved to base/Budget.h (below core and io, issue 26); this header keeps existing includes working.
#include <frostvdb/base/Budget.h>
