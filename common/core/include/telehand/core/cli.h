#pragma once
// Moved to the program library: telehand/app/cli.h (target telehand::app). This name stays
// for the test programs that still include it.
#include "../../../../app/include/telehand/app/cli.h"
