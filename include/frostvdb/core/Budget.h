#pragma once
/// @file Budget.h
/// @brief Forwards to base/Budget.h, where it lives (below io and core: issue 26's folder order).
/// New code includes <frostvdb/base/Budget.h>.
#include <frostvdb/base/Budget.h>
