#include <kelvin/core/math.h>

#include <glm/gtc/matrix_transform.hpp>

#include <cmath>

namespace kelvin {

Transform::Transform(const Mat4d& m) : matrix(m), inverse(glm::inverse(m)) {}

Vec3d Transform::apply_point(const Vec3d& p) const {
    glm::dvec4 r = matrix * glm::dvec4(p, 1.0);
    return r.w == 1.0 ? Vec3d(r) : Vec3d(r) / r.w;
}
Vec3d Transform::apply_vector(const Vec3d& v) const { return Vec3d(matrix * glm::dvec4(v, 0.0)); }
Vec3d Transform::apply_normal(const Vec3d& n) const { return Vec3d(glm::transpose(inverse) * glm::dvec4(n, 0.0)); }

bool Transform::is_rigid(double tol) const {
    const Mat3d m(matrix);
    const Mat3d mtm = glm::transpose(m) * m;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            if (std::abs(mtm[i][j] - (i == j ? 1.0 : 0.0)) > tol) return false;
    return true;
}

Transform Transform::translate(const Vec3d& t) {
    return {glm::translate(Mat4d(1.0), t), glm::translate(Mat4d(1.0), -t)};
}
Transform Transform::scale(const Vec3d& s) { return {glm::scale(Mat4d(1.0), s), glm::scale(Mat4d(1.0), 1.0 / s)}; }
Transform Transform::rotate(const Vec3d& axis, double angle_deg) {
    Mat4d m = glm::rotate(Mat4d(1.0), glm::radians(angle_deg), glm::normalize(axis));
    return {m, glm::transpose(m)};
}
Transform Transform::look_at(const Vec3d& origin, const Vec3d& target, const Vec3d& up) {
    Vec3d dir = glm::normalize(target - origin);
    Vec3d left = glm::normalize(glm::cross(up, dir));
    Vec3d new_up = glm::cross(dir, left);
    Mat4d m(1.0);
    m[0] = glm::dvec4(left, 0);
    m[1] = glm::dvec4(new_up, 0);
    m[2] = glm::dvec4(dir, 0);
    m[3] = glm::dvec4(origin, 1);
    return Transform(m);
}

}  // namespace kelvin
