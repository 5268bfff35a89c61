#pragma once
/// @file Error.h
/// @brief Forwards to base/Error.h, where it lives (below io and core: issue 26's folder order).
/// New code includes <frostvdb/base/Error.h>.
#include <frostvdb/base/Error.h>
