// Helpers shared by the core's gtests.
#pragma once

#include <functional>
#include <stdexcept>
#include <string>

// The message of the std::invalid_argument that `build` throws, or "" when it throws none.
inline std::string refusal(const std::function<void()>& build)
{
  try
  {
    build();
  }
  catch (const std::invalid_argument& e)
  {
    return e.what();
  }
  return "";
}

inline bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }
