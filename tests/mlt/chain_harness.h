#pragma once
// The chain harness is installed with Kelvin (kelvin/testing/chain_harness.h) for out-of-tree plugin tests; the
// in-tree tests use it as ktest::... next to the shared test support.
#include "common/support.h"

#include <kelvin/testing/chain_harness.h>

namespace ktest {
using namespace kelvin;
using namespace kelvin::testkit;
}  // namespace ktest
