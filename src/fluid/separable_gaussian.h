#pragma once
// The Gaussian smoothing behind gaussian_filter (grid.h, grid3.h), on a cell array of 2 or 3 dimensions.
#include <vector>

namespace kelvin::fluid::detail {

/// Smooths `values` (x fastest, then y, then z; n[2] = 1 in 2D) with a Gaussian of `sigma` cells, separable and
/// truncated at 3 sigma, one axis at a time: wrapped when `periodic`, else (and around the cells `fluid` marks 0) a
/// normalised convolution, the weights of the cells it may read renormalised; cells marked 0 keep their values.
/// Lines are independent: the same bits on any thread count.
void separable_gaussian(std::vector<double>& values, const int (&n)[3], bool periodic, double sigma,
                        const std::vector<char>* fluid);
/// separable_gaussian, or with `twicing` 2 G v - G G v (FilterKernel::Twicing, grid.h).
void smooth_values(std::vector<double>& values, const int (&n)[3], bool periodic, double sigma, bool twicing,
                   const std::vector<char>* fluid);

}  // namespace kelvin::fluid::detail
