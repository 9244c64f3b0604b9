// The clocks the package's costs are measured with: CPU time, which other work on the machine's
// cores does not inflate as it does wall time.
#pragma once

#include <time.h>

namespace modal_mass_spring
{

namespace detail
{
inline double seconds(clockid_t clock)
{
  timespec t{};
  clock_gettime(clock, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}
}  // namespace detail

// This thread's CPU time (s).
inline double threadCpuSeconds() { return detail::seconds(CLOCK_THREAD_CPUTIME_ID); }

// The process's CPU time (s), every thread's.
inline double processCpuSeconds() { return detail::seconds(CLOCK_PROCESS_CPUTIME_ID); }

}  // namespace modal_mass_spring
