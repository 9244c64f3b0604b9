// Throttling of the warnings about dropped messages (~apply_force, /clicked_point, drag poses): each
// distinct warning at most once per period, so that a second, different mistake right after a first is
// still told, and at most `burst` warnings of any kind per period, so that a flood of bad messages
// does not flood the log. ROS_WARN_THROTTLE throttles per call site, which hides the second mistake.
#pragma once

#include <iterator>
#include <map>
#include <string>

namespace modal_mass_spring
{

class WarningThrottle
{
public:
  explicit WarningThrottle(double period = 1.0, int burst = 10) : period_(period), burst_(burst) {}

  // Whether `text` may be logged at `now` (seconds); counts it when it may.
  bool allow(const std::string& text, double now)
  {
    if (now - window_start_ >= period_)
    {
      window_start_ = now;
      in_window_ = 0;
    }
    for (auto it = last_.begin(); it != last_.end();)  // forget the ones whose period is over
      it = now - it->second >= period_ ? last_.erase(it) : std::next(it);
    if (last_.count(text) > 0 || in_window_ >= burst_)
      return false;
    last_[text] = now;
    ++in_window_;
    return true;
  }

private:
  double period_;
  int burst_;
  std::map<std::string, double> last_;  // text -> when it was last logged
  double window_start_ = -1e300;
  int in_window_ = 0;
};

}  // namespace modal_mass_spring
