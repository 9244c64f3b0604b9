// A thread's CPU time, for the node's costs: what work costs whatever else shares the machine's cores.
#pragma once

#include <time.h>

namespace modal_mass_spring
{

// This thread's CPU time (s).
inline double threadCpuSeconds()
{
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

}  // namespace modal_mass_spring
