#pragma once
// FFTW's planner is not thread-safe (fftw_execute is): every plan in the fluid library is made and destroyed under
// this one lock (pressure.cpp, pressure3.cpp, energy_budget.cpp).
#include <mutex>

namespace kelvin::fluid {
std::mutex& fftw_planner_mutex();
}
