#include "fitting/scene.h"

#include <embree3/rtcore.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "core/error.h"
#include "fitting/fit.h"
#include "tomography/ray_march.h"

namespace flamerig {

namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point since) {
  return std::chrono::duration<double, std::milli>(Clock::now() - since).count();
}

// Random numbers that depend only on (seed, pixel, pass, sample): SplitMix64.
struct Random {
  std::uint64_t state;
  explicit Random(std::uint64_t seed) : state(seed) {}
  std::uint64_t Next() {
    std::uint64_t z = (state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  double Uniform() { return (Next() >> 11) * 0x1.0p-53; }  // [0, 1)
};

std::uint64_t Mix(std::uint64_t a, std::uint64_t b) {
  Random r(a * 0x100000001B3ull ^ b);
  return r.Next();
}

double Luminance(const Eigen::Vector3d& rgb) {
  return 0.2126 * rgb.x() + 0.7152 * rgb.y() + 0.0722 * rgb.z();
}

Eigen::Matrix3d RotationY(double degrees) {
  return Eigen::AngleAxisd(degrees * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
}

constexpr double kInf = std::numeric_limits<double>::infinity();

}  // namespace

const char* ToString(SceneLighting lighting) {
  switch (lighting) {
    case SceneLighting::kFireVolume:
      return "fire";
    case SceneLighting::kPointLight:
      return "point";
    case SceneLighting::kSphereLight:
      return "sphere";
  }
  return "?";
}

SceneLighting SceneLightingFromName(const std::string& name) {
  if (name == "fire") return SceneLighting::kFireVolume;
  if (name == "point") return SceneLighting::kPointLight;
  if (name == "sphere") return SceneLighting::kSphereLight;
  throw InputError("lighting '" + name + "': use fire, point or sphere");
}

void SceneMaterial::Validate() const {
  auto in01 = [&](const Eigen::Vector3d& v, const char* field) {
    if (!v.allFinite() || v.minCoeff() < 0 || v.maxCoeff() > 1)
      throw InputError("material '" + name + "': " + field + " must be in [0, 1]");
  };
  in01(albedo, "albedo");
  in01(specular, "specular");
  if ((albedo + specular).maxCoeff() > 1)
    throw InputError("material '" + name +
                                "': albedo + specular above 1 would reflect more than it receives");
  if (!(shininess >= 1) || !(shininess <= 1e5))
    throw InputError("material '" + name + "': shininess must be in [1, 1e5]");
}

void SceneCamera::Validate() const {
  if (!position.allFinite() || !look_at.allFinite() || !up.allFinite())
    throw InputError("camera: position, look_at and up must be finite");
  if ((look_at - position).norm() < 1e-9)
    throw InputError("camera: look_at must differ from position");
  if ((look_at - position).normalized().cross(up).norm() < 1e-6)
    throw InputError("camera: up must not be parallel to the viewing direction");
  if (!(vertical_fov_deg > 0) || !(vertical_fov_deg < 170))
    throw InputError("camera: fov_deg must be in (0, 170)");
  if (width < 1 || height < 1 || width > 16384 || height > 16384)
    throw InputError("camera: width and height must be in [1, 16384]");
}

void SceneRenderOptions::Validate() const {
  if (samples_per_pixel < 1) throw InputError("samples must be >= 1");
  if (samples_per_pass < 1) throw InputError("samples_per_pass must be >= 1");
  if (!(sphere_light_radius_m >= 0) || !std::isfinite(sphere_light_radius_m))
    throw InputError("sphere_light_radius_m must be finite and >= 0");
  fire.Validate();
}

void SceneGeometry::AddQuad(const Eigen::Vector3d& centre, const Eigen::Vector3d& normal,
                            const Eigen::Vector2d& size, int material) {
  const Eigen::Vector3d n = normal.normalized();
  const Eigen::Vector3d helper =
      std::abs(n.y()) < 0.9 ? Eigen::Vector3d::UnitY() : Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d u = helper.cross(n).normalized(), v = n.cross(u);
  const int base = static_cast<int>(vertices.size());
  for (int k = 0; k < 4; ++k) {
    const double a = (k == 1 || k == 2) ? 0.5 : -0.5, b = k >= 2 ? 0.5 : -0.5;
    vertices.push_back((centre + a * size.x() * u + b * size.y() * v).cast<float>());
  }
  triangles.emplace_back(base, base + 1, base + 2);
  triangles.emplace_back(base, base + 2, base + 3);
  triangle_material.insert(triangle_material.end(), 2, material);
}

void SceneGeometry::AddBox(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, int material) {
  const Eigen::Vector3d c = 0.5 * (lo + hi), e = hi - lo;
  AddQuad(c + Eigen::Vector3d(0.5 * e.x(), 0, 0), Eigen::Vector3d::UnitX(), {e.z(), e.y()},
          material);
  AddQuad(c - Eigen::Vector3d(0.5 * e.x(), 0, 0), -Eigen::Vector3d::UnitX(), {e.z(), e.y()},
          material);
  AddQuad(c + Eigen::Vector3d(0, 0.5 * e.y(), 0), Eigen::Vector3d::UnitY(), {e.x(), e.z()},
          material);
  AddQuad(c - Eigen::Vector3d(0, 0.5 * e.y(), 0), -Eigen::Vector3d::UnitY(), {e.x(), e.z()},
          material);
  AddQuad(c + Eigen::Vector3d(0, 0, 0.5 * e.z()), Eigen::Vector3d::UnitZ(), {e.x(), e.y()},
          material);
  AddQuad(c - Eigen::Vector3d(0, 0, 0.5 * e.z()), -Eigen::Vector3d::UnitZ(), {e.x(), e.y()},
          material);
}

void SceneGeometry::AddMesh(const std::vector<Eigen::Vector3f>& v,
                            const std::vector<Eigen::Vector3i>& t, int material) {
  const int base = static_cast<int>(vertices.size());
  vertices.insert(vertices.end(), v.begin(), v.end());
  for (const auto& tri : t) {
    if ((tri.array() < 0).any() || (tri.array() >= static_cast<int>(v.size())).any())
      throw InputError("mesh: a triangle refers to a vertex it does not have");
    triangles.push_back(tri + Eigen::Vector3i::Constant(base));
    triangle_material.push_back(material);
  }
}

std::string SceneRenderSummary::BriefReport() const {
  std::ostringstream s;
  s.precision(4);
  s << ToString(lighting) << " lighting, " << samples_per_pixel << " samples per pixel, "
    << light.emitting_voxels << " emitting voxels (hottest " << light.hottest_k
    << " K), total intensity " << Luminance(light.intensity_rgb) << " (luminance), "
    << surface_pixels << " surface pixels, " << shadow_rays << " shadow rays; " << total_ms
    << " ms (fire " << fire_ms << ", lighting " << lighting_ms << ")";
  return s.str();
}

struct SceneRenderer::Impl {
  struct Fire {
    GridGeometry grid;
    std::vector<float> density;
    Eigen::Vector3d sigma_rgb;  // cross-sections at 610, 550, 465 nm
    Eigen::Matrix3d rotation;   // scene_from_rig = translate + scale * rotation
    double scale = 1;
    Eigen::Vector3d translate;
    double max_optical_depth = 0;  // a bound over the box: skip transmittance when tiny
    Eigen::Vector3d ToRig(const Eigen::Vector3d& p) const {
      return rotation.transpose() * (p - translate) / scale;
    }
    Eigen::Vector3d ToScene(const Eigen::Vector3d& p) const {
      return translate + scale * (rotation * p);
    }
  };
  struct Emitter {
    int fire;
    std::uint32_t voxel;
    Eigen::Vector3d intensity;  // scene units: radiance x m^2
  };

  Scene scene;
  RTCDevice device = nullptr;
  RTCScene rtc = nullptr;
  unsigned triangle_geometry = RTC_INVALID_GEOMETRY_ID, sphere_geometry = RTC_INVALID_GEOMETRY_ID;
  std::vector<Fire> fires;
  std::vector<Emitter> emitters;  // sorted by brick
  std::vector<double> cdf;        // cumulative luminance of the emitters, normalised to 1
  // Emitters grouped in bricks of kBrick^3 voxels, for sampling by power over distance squared.
  struct Brick {
    std::size_t first = 0, count = 0;  // emitters[first, first + count)
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    double radius = 0;     // half its diagonal, scene metres
    double luminance = 0;  // of its emitters' intensities
  };
  static constexpr int kBrick = 4;
  std::vector<Brick> bricks;
  double total_luminance = 0;
  SceneLight light;
  double min_distance_m = 1e-4;  // light samples closer than this are clamped (half a voxel)

  ~Impl() {
    if (rtc) rtcReleaseScene(rtc);
    if (device) rtcReleaseDevice(device);
  }

  // The nearest surface along a ray: distance (kInf if none), normal facing the ray, material.
  double Intersect(const Eigen::Vector3d& o, const Eigen::Vector3d& d, Eigen::Vector3d* normal,
                   int* material) const {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRayHit rh;
    rh.ray.org_x = static_cast<float>(o.x());
    rh.ray.org_y = static_cast<float>(o.y());
    rh.ray.org_z = static_cast<float>(o.z());
    rh.ray.dir_x = static_cast<float>(d.x());
    rh.ray.dir_y = static_cast<float>(d.y());
    rh.ray.dir_z = static_cast<float>(d.z());
    rh.ray.tnear = 0;
    rh.ray.tfar = std::numeric_limits<float>::infinity();
    rh.ray.mask = ~0u;
    rh.ray.flags = 0;
    rh.ray.time = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(rtc, &context, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return kInf;
    Eigen::Vector3d n(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
    n.normalize();
    if (n.dot(d) > 0) n = -n;  // two-sided surfaces
    *normal = n;
    *material = rh.hit.geomID == triangle_geometry ? scene.geometry.triangle_material[rh.hit.primID]
                                                   : scene.geometry.spheres[rh.hit.primID].material;
    return rh.ray.tfar;
  }

  bool Occluded(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double distance) const {
    if (!rtc) return false;
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRay r;
    r.org_x = static_cast<float>(o.x());
    r.org_y = static_cast<float>(o.y());
    r.org_z = static_cast<float>(o.z());
    r.dir_x = static_cast<float>(d.x());
    r.dir_y = static_cast<float>(d.y());
    r.dir_z = static_cast<float>(d.z());
    r.tnear = 0;
    r.tfar = static_cast<float>(distance);
    r.mask = ~0u;
    r.flags = 0;
    r.time = 0;
    rtcOccluded1(rtc, &context, &r);
    return r.tfar == -std::numeric_limits<float>::infinity();
  }

  // Transmittance of the fires between two scene points, per channel.
  Eigen::Vector3d Transmittance(const Eigen::Vector3d& a, const Eigen::Vector3d& b) const {
    Eigen::Vector3d tau = Eigen::Vector3d::Zero();
    for (const Fire& f : fires) {
      if (f.max_optical_depth < 1e-6) continue;
      const Eigen::Vector3d ar = f.ToRig(a), br = f.ToRig(b);
      const double length = (br - ar).norm();
      if (!(length > 0)) continue;
      Ray ray;
      ray.origin_in_rig = ar;
      ray.direction_in_rig = (br - ar) / length;
      ray.valid = true;
      RayMarch march;
      const double step = f.grid.voxel_size_m.minCoeff();
      if (!RayMarch::Make(f.grid, ray, step, &march)) continue;
      if (!(length > march.t_enter)) continue;
      if (length < march.t_exit) {
        march.t_exit = length;
        march.n_steps = std::max<std::int64_t>(
            1, static_cast<std::int64_t>(std::ceil((march.t_exit - march.t_enter) / step - 1e-9)));
      }
      const std::size_t nx = f.grid.dims.x(), nxy = nx * f.grid.dims.y();
      double column = 0;  // integral of n ds, rig metres
      for (std::int64_t k = 0; k < march.n_steps; ++k) {
        double ds;
        Eigen::Vector3d mid;
        march.Step(k, &ds, &mid);
        const TrilinearStencil<double> s(f.grid.dims, mid.x(), mid.y(), mid.z());
        column += s.Sample(f.density.data(), nx, nxy) * ds;
      }
      tau += f.sigma_rgb * column;  // kappa ds is scale-free: rig kappa times rig length
    }
    return (-tau).array().exp().matrix();
  }

  // One light sample's irradiance at p (normal n), and its incoming direction.
  // `stratum` of `strata`: the emitter is chosen in that slice of the power CDF (stratified
  // sampling across a pixel's samples: unbiased, and neighbouring voxels of the CDF are neighbours
  // in space, so the samples spread over the fire).
  Eigen::Vector3d SampleIrradiance(const Eigen::Vector3d& p, const Eigen::Vector3d& n,
                                   SceneLighting lighting, double sphere_radius, Random* rng,
                                   Eigen::Vector3d* incoming, std::int64_t* shadow_rays,
                                   const std::vector<double>& brick_cdf, int stratum = 0,
                                   int strata = 1) const {
    if (emitters.empty()) return Eigen::Vector3d::Zero();
    Eigen::Vector3d x, intensity;
    bool through_fire = false;
    if (lighting == SceneLighting::kFireVolume) {
      // A brick by its power over its distance squared (brick_cdf, for this point), then a voxel
      // of it by power: probability (w_b / W) (Y_e / Y_b).
      const double u = (stratum + rng->Uniform()) / strata;
      const std::size_t b = std::min<std::size_t>(
          bricks.size() - 1,
          std::upper_bound(brick_cdf.begin(), brick_cdf.end(), u) - brick_cdf.begin());
      const Brick& brick = bricks[b];
      const double lo = brick.first == 0 ? 0.0 : cdf[brick.first - 1];
      const double hi = cdf[brick.first + brick.count - 1];
      const double v = lo + rng->Uniform() * (hi - lo);
      const auto begin = cdf.begin() + static_cast<std::ptrdiff_t>(brick.first);
      const std::size_t e = std::min<std::size_t>(
          brick.first + brick.count - 1,
          std::upper_bound(begin, begin + static_cast<std::ptrdiff_t>(brick.count), v) -
              cdf.begin());
      const Emitter& em = emitters[e];
      const Fire& f = fires[em.fire];
      const std::size_t nx = f.grid.dims.x(), ny = f.grid.dims.y();
      const int i = static_cast<int>(em.voxel % nx), j = static_cast<int>((em.voxel / nx) % ny),
                k = static_cast<int>(em.voxel / (nx * ny));
      const Eigen::Vector3d jitter(rng->Uniform() - 0.5, rng->Uniform() - 0.5,
                                   rng->Uniform() - 0.5);
      x = f.ToScene(f.grid.VoxelCenter(i, j, k) + jitter.cwiseProduct(f.grid.voxel_size_m));
      const double brick_probability = brick_cdf[b] - (b == 0 ? 0.0 : brick_cdf[b - 1]);
      const double probability = brick_probability * Luminance(em.intensity) / brick.luminance;
      intensity = em.intensity / probability;
      through_fire = true;
    } else {
      const Eigen::Vector3d colour =
          light.hottest_rgb * Luminance(light.intensity_rgb) / Luminance(light.hottest_rgb);
      x = light.centroid;
      if (lighting == SceneLighting::kSphereLight && sphere_radius > 0) {
        Eigen::Vector3d q;
        do {
          q = Eigen::Vector3d(2 * rng->Uniform() - 1, 2 * rng->Uniform() - 1,
                              2 * rng->Uniform() - 1);
        } while (q.squaredNorm() > 1);
        x += sphere_radius * q;
      }
      intensity = colour;
    }
    Eigen::Vector3d to_light = x - p;
    const double d = to_light.norm();
    if (!(d > 0)) return Eigen::Vector3d::Zero();
    to_light /= d;
    *incoming = to_light;
    const double cosine = n.dot(to_light);
    if (cosine <= 0) return Eigen::Vector3d::Zero();
    ++*shadow_rays;
    const double eps = 1e-5 * std::max(1.0, p.norm());
    if (Occluded(p + eps * n, to_light, d - 2 * eps)) return Eigen::Vector3d::Zero();
    Eigen::Vector3d e = intensity * cosine / std::max(d * d, min_distance_m * min_distance_m);
    if (through_fire) e = e.cwiseProduct(Transmittance(x, p));
    return e;
  }

  // The cumulative brick probabilities for a shading point: brick power over the square of its
  // distance, never nearer than its own radius (every brick keeps a weight > 0: unbiased).
  void BrickCdf(const Eigen::Vector3d& p, std::vector<double>* out) const {
    out->resize(bricks.size());
    double acc = 0;
    for (std::size_t b = 0; b < bricks.size(); ++b) {
      const double d = std::max((bricks[b].centre - p).norm() - bricks[b].radius, bricks[b].radius);
      acc += bricks[b].luminance / (d * d);
      (*out)[b] = acc;
    }
    for (double& c : *out) c /= acc;
    if (!out->empty()) out->back() = 1.0;
  }

  // Reflected radiance towards `outgoing` for light arriving from `incoming` (unit vectors).
  static Eigen::Vector3d Brdf(const SceneMaterial& m, const Eigen::Vector3d& n,
                              const Eigen::Vector3d& incoming, const Eigen::Vector3d& outgoing) {
    Eigen::Vector3d f = m.albedo / M_PI;
    if (m.specular.maxCoeff() > 0) {
      const Eigen::Vector3d h = (incoming + outgoing).normalized();
      const double c = std::max(0.0, n.dot(h));
      f += m.specular * (m.shininess + 8) / (8 * M_PI) * std::pow(c, m.shininess);
    }
    return f;
  }
};

SceneRenderer::SceneRenderer(const Scene& scene) : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.scene = scene;
  scene.camera.Validate();
  for (const auto& mat : scene.materials) mat.Validate();
  const SceneGeometry& g = scene.geometry;
  const int nmat = static_cast<int>(scene.materials.size());
  if (g.triangle_material.size() != g.triangles.size())
    throw InputError("scene: every triangle needs a material");
  for (int mat : g.triangle_material)
    if (mat < 0 || mat >= nmat) throw InputError("scene: a surface has no material");
  for (const auto& s : g.spheres) {
    if (s.material < 0 || s.material >= nmat)
      throw InputError("scene: a sphere has no material");
    if (!(s.radius > 0) || !s.centre.allFinite())
      throw InputError("scene: a sphere needs a finite centre and a radius > 0");
  }
  for (const auto& v : g.vertices)
    if (!v.allFinite()) throw InputError("scene: a vertex is not finite");

  // Embree: the triangles and the spheres.
  m.device = rtcNewDevice(nullptr);
  if (!m.device) throw IoError("scene: Embree could not create a device");
  m.rtc = rtcNewScene(m.device);
  if (!g.triangles.empty()) {
    RTCGeometry geom = rtcNewGeometry(m.device, RTC_GEOMETRY_TYPE_TRIANGLE);
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(
        geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), g.vertices.size()));
    for (std::size_t i = 0; i < g.vertices.size(); ++i)
      for (int c = 0; c < 3; ++c) v[3 * i + c] = g.vertices[i][c];
    auto* t = static_cast<unsigned*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0,
                                                             RTC_FORMAT_UINT3, 3 * sizeof(unsigned),
                                                             g.triangles.size()));
    for (std::size_t i = 0; i < g.triangles.size(); ++i)
      for (int c = 0; c < 3; ++c) t[3 * i + c] = static_cast<unsigned>(g.triangles[i][c]);
    rtcCommitGeometry(geom);
    m.triangle_geometry = rtcAttachGeometry(m.rtc, geom);
    rtcReleaseGeometry(geom);
  }
  if (!g.spheres.empty()) {
    RTCGeometry geom = rtcNewGeometry(m.device, RTC_GEOMETRY_TYPE_SPHERE_POINT);
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(
        geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), g.spheres.size()));
    for (std::size_t i = 0; i < g.spheres.size(); ++i) {
      for (int c = 0; c < 3; ++c) v[4 * i + c] = static_cast<float>(g.spheres[i].centre[c]);
      v[4 * i + 3] = static_cast<float>(g.spheres[i].radius);
    }
    rtcCommitGeometry(geom);
    m.sphere_geometry = rtcAttachGeometry(m.rtc, geom);
    rtcReleaseGeometry(geom);
  }
  rtcCommitScene(m.rtc);

  // The fires: renderers for the camera rays, and the emitting voxels as lights.
  double weighted = 0;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  double smallest_voxel = kInf;
  for (std::size_t fi = 0; fi < scene.fires.size(); ++fi) {
    const SceneFire& sf = scene.fires[fi];
    const GridGeometry& grid = sf.volume.geometry;
    const std::size_t n = grid.num_voxels();
    const std::string name = "fire " + std::to_string(fi);
    if (sf.volume.temperature_k.size() != n || sf.volume.density_per_m3.size() != n)
      throw InputError("scene: " + name + " needs temperature and density grids");
    if (!(sf.scale > 0) || !std::isfinite(sf.scale))
      throw InputError("scene: " + name + " needs a finite scale > 0");
    Impl::Fire f;
    FireRenderer(sf.absorption)
        .SetVolume(grid, sf.volume.temperature_k,
                   sf.volume.density_per_m3);  // validates the fields
    f.grid = grid;
    f.density = sf.volume.density_per_m3;
    f.sigma_rgb =
        Eigen::Vector3d(sf.absorption.CrossSectionM2(610), sf.absorption.CrossSectionM2(550),
                        sf.absorption.CrossSectionM2(465));
    f.rotation = RotationY(sf.rotate_y_deg);
    f.scale = sf.scale;
    f.translate = sf.translate;
    float n_max = 0, t_lo = 1e30f, t_hi = 0;
    for (std::size_t v = 0; v < n; ++v) {
      if (!(sf.volume.density_per_m3[v] > 0)) continue;
      n_max = std::max(n_max, sf.volume.density_per_m3[v]);
      t_lo = std::min(t_lo, sf.volume.temperature_k[v]);
      t_hi = std::max(t_hi, sf.volume.temperature_k[v]);
    }
    f.max_optical_depth = f.sigma_rgb.maxCoeff() * n_max * grid.box().size().norm();
    smallest_voxel = std::min(smallest_voxel, sf.scale * grid.voxel_size_m.minCoeff());
    if (n_max > 0) {
      const ThinEmissionTable table(sf.absorption, std::max(1.0, std::floor(double(t_lo))),
                                    std::max(2.0, std::ceil(double(t_hi)) + 1));
      const double volume_rig = grid.voxel_size_m.prod();
      for (std::size_t v = 0; v < n; ++v) {
        const double density = sf.volume.density_per_m3[v];
        if (!(density > 0)) continue;
        // I = j V: emission per rig metre / scale, times the voxel's volume * scale^3.
        const Eigen::Vector3d intensity = density *
                                          table.RgbPerDensity(sf.volume.temperature_k[v]) *
                                          volume_rig * sf.scale * sf.scale;
        const double y = Luminance(intensity);
        if (!(y > 0) || !intensity.allFinite()) continue;
        m.emitters.push_back({static_cast<int>(fi), static_cast<std::uint32_t>(v), intensity});
        m.light.intensity_rgb += intensity;
        const std::size_t nx = grid.dims.x(), ny = grid.dims.y();
        const Eigen::Vector3d c =
            f.ToScene(grid.VoxelCenter(static_cast<int>(v % nx), static_cast<int>((v / nx) % ny),
                                       static_cast<int>(v / (nx * ny))));
        centroid += y * c;
        weighted += y;
      }
    }
    m.fires.push_back(std::move(f));
  }
  if (std::isfinite(smallest_voxel)) m.min_distance_m = 0.5 * smallest_voxel;
  m.light.emitting_voxels = m.emitters.size();
  // Group the emitters by brick (stable: voxel order inside a brick).
  auto brick_key = [&](const Impl::Emitter& e) {
    const GridGeometry& g = m.fires[e.fire].grid;
    const std::size_t nx = g.dims.x(), ny = g.dims.y();
    const std::size_t i = e.voxel % nx, j = (e.voxel / nx) % ny, k = e.voxel / (nx * ny);
    const std::size_t bx = (nx + Impl::kBrick - 1) / Impl::kBrick,
                      by = (ny + Impl::kBrick - 1) / Impl::kBrick;
    return std::make_pair(e.fire,
                          i / Impl::kBrick + bx * (j / Impl::kBrick + by * (k / Impl::kBrick)));
  };
  std::stable_sort(
      m.emitters.begin(), m.emitters.end(),
      [&](const Impl::Emitter& a, const Impl::Emitter& b) { return brick_key(a) < brick_key(b); });
  for (std::size_t e = 0; e < m.emitters.size(); ++e) {
    if (e == 0 || brick_key(m.emitters[e]) != brick_key(m.emitters[e - 1])) {
      m.bricks.emplace_back();
      m.bricks.back().first = e;
    }
    Impl::Brick& b = m.bricks.back();
    ++b.count;
    const double y = Luminance(m.emitters[e].intensity);
    const Impl::Fire& f = m.fires[m.emitters[e].fire];
    const std::size_t nx = f.grid.dims.x(), ny = f.grid.dims.y();
    const std::uint32_t v = m.emitters[e].voxel;
    b.centre +=
        y * f.ToScene(f.grid.VoxelCenter(static_cast<int>(v % nx), static_cast<int>((v / nx) % ny),
                                         static_cast<int>(v / (nx * ny))));
    b.luminance += y;
  }
  for (Impl::Brick& b : m.bricks) {
    b.centre /= b.luminance;  // power-weighted centre; the radius covers the whole brick
    const Impl::Fire& f = m.fires[m.emitters[b.first].fire];
    b.radius = std::sqrt(3.0) * Impl::kBrick * f.scale * f.grid.voxel_size_m.maxCoeff();
  }
  if (weighted > 0) {
    m.total_luminance = weighted;
    m.light.centroid = centroid / weighted;
    double acc = 0, spread = 0, peak = 0;
    for (const auto& e : m.emitters) peak = std::max(peak, Luminance(e.intensity));
    m.cdf.reserve(m.emitters.size());
    for (const auto& e : m.emitters) {
      const double y = Luminance(e.intensity);
      acc += y;
      m.cdf.push_back(acc / weighted);
      const Impl::Fire& f = m.fires[e.fire];
      const std::size_t nx = f.grid.dims.x(), ny = f.grid.dims.y();
      const Eigen::Vector3d c = f.ToScene(
          f.grid.VoxelCenter(static_cast<int>(e.voxel % nx), static_cast<int>((e.voxel / nx) % ny),
                             static_cast<int>(e.voxel / (nx * ny))));
      spread += y * (c - m.light.centroid).squaredNorm();
      // The hottest voxel among those bright enough to be seen (1e-3 of the brightest).
      const float t = scene.fires[e.fire].volume.temperature_k[e.voxel];
      if (y >= 1e-3 * peak && t > m.light.hottest_k) {
        m.light.hottest_k = t;
        m.light.hottest_rgb = e.intensity / y;
      }
    }
    m.cdf.back() = 1.0;
    m.light.rms_radius_m = std::sqrt(spread / weighted);
  }
}

SceneRenderer::~SceneRenderer() = default;

const SceneLight& SceneRenderer::light() const { return impl_->light; }

Eigen::Vector3d SceneRenderer::Irradiance(const Eigen::Vector3d& point,
                                          const Eigen::Vector3d& normal, SceneLighting lighting,
                                          int samples, std::uint64_t seed,
                                          double sphere_radius_m) const {
  Random rng(Mix(seed, 0x5eed));
  Eigen::Vector3d sum = Eigen::Vector3d::Zero(), incoming;
  std::int64_t shadow_rays = 0;
  const double radius = sphere_radius_m > 0 ? sphere_radius_m : impl_->light.rms_radius_m;
  std::vector<double> brick_cdf;
  impl_->BrickCdf(point, &brick_cdf);
  for (int k = 0; k < samples; ++k)
    sum += impl_->SampleIrradiance(point, normal.normalized(), lighting, radius, &rng, &incoming,
                                   &shadow_rays, brick_cdf, k, samples);
  return samples > 0 ? Eigen::Vector3d(sum / samples) : sum;
}

SceneRenderSummary SceneRenderer::Render(const SceneRenderOptions& options, ImageF* linear_rgb,
                                         const ProgressCallback& progress) const {
  options.Validate();
  const auto start = Clock::now();
  const Impl& m = *impl_;
  const SceneCamera& cam = m.scene.camera;
  const int width = cam.width, height = cam.height;
  SceneRenderSummary summary;
  summary.light = m.light;
  summary.lighting = options.lighting;
  summary.samples_per_pixel = options.samples_per_pixel;
  const double sphere_radius =
      options.sphere_light_radius_m > 0 ? options.sphere_light_radius_m : m.light.rms_radius_m;

  // Camera rays through the pixel centres.
  const Eigen::Vector3d forward = (cam.look_at - cam.position).normalized();
  const Eigen::Vector3d right = forward.cross(cam.up).normalized();
  const Eigen::Vector3d down = forward.cross(right);  // image y grows downwards
  const double tan_half = std::tan(0.5 * cam.vertical_fov_deg * M_PI / 180.0);
  const double aspect = double(width) / height;
  auto direction = [&](int x, int y) {
    const double u = (2 * (x + 0.5) / width - 1) * tan_half * aspect;
    const double v = (2 * (y + 0.5) / height - 1) * tan_half;
    return (forward + u * right + v * down).normalized();
  };
  // First surfaces.
  const std::size_t npix = static_cast<std::size_t>(width) * height;
  std::vector<float> hit_distance(npix, std::numeric_limits<float>::infinity());
  std::vector<Eigen::Vector3f> hit_normal(npix);
  std::vector<int> hit_material(npix, -1);
  tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y)
      for (int x = 0; x < width; ++x) {
        const std::size_t p = static_cast<std::size_t>(y) * width + x;
        Eigen::Vector3d n;
        int material;
        const double t = m.Intersect(cam.position, direction(x, y), &n, &material);
        if (std::isfinite(t)) {
          hit_distance[p] = static_cast<float>(t);
          hit_normal[p] = n.cast<float>();
          hit_material[p] = material;
        }
      }
  });
  // The fires along the camera rays, up to the surfaces.
  auto t0 = Clock::now();
  ImageF fire_rgb(width, height, 3, 0.0f), fire_tr(width, height, 3, 1.0f);
  for (const Impl::Fire& f : m.fires) {
    std::vector<Ray> rays(npix);
    std::vector<float> stop(npix);
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x) {
        const std::size_t p = static_cast<std::size_t>(y) * width + x;
        rays[p].origin_in_rig = f.ToRig(cam.position);
        rays[p].direction_in_rig = f.rotation.transpose() * direction(x, y);
        rays[p].valid = true;
        stop[p] = hit_distance[p] / static_cast<float>(f.scale);
      }
    const CameraRays camera_rays(width, height, std::move(rays));
    ImageF rgb, tr;
    FireRenderer renderer(m.scene.fires[&f - m.fires.data()].absorption, options.fire);
    renderer.SetVolume(f.grid, m.scene.fires[&f - m.fires.data()].volume.temperature_k, f.density);
    renderer.Render(camera_rays, stop, &rgb, &tr);
    for (std::size_t i = 0; i < rgb.pixels.size(); ++i) {
      fire_rgb.pixels[i] += rgb.pixels[i];
      fire_tr.pixels[i] *= tr.pixels[i];
    }
  }
  summary.fire_ms = Ms(t0);

  // Direct light on the surfaces, pass by pass.
  t0 = Clock::now();
  ImageF sum(width, height, 3, 0.0f);
  std::atomic<std::int64_t> shadow_rays{0}, surfaces{0};
  const int passes =
      (options.samples_per_pixel + options.samples_per_pass - 1) / options.samples_per_pass;
  int done = 0;
  for (int pass = 0; pass < passes; ++pass) {
    const int samples = std::min(options.samples_per_pass, options.samples_per_pixel - done);
    tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& r) {
      std::int64_t rays = 0, hits = 0;
      std::vector<double> brick_cdf;
      for (int y = r.begin(); y < r.end(); ++y)
        for (int x = 0; x < width; ++x) {
          const std::size_t p = static_cast<std::size_t>(y) * width + x;
          if (hit_material[p] < 0) continue;
          ++hits;
          const Eigen::Vector3d d = direction(x, y);
          const Eigen::Vector3d point = cam.position + double(hit_distance[p]) * d;
          const Eigen::Vector3d n = hit_normal[p].cast<double>();
          const SceneMaterial& mat = m.scene.materials[hit_material[p]];
          Random rng(Mix(Mix(options.seed, p), static_cast<std::uint64_t>(pass)));
          if (options.lighting == SceneLighting::kFireVolume) m.BrickCdf(point, &brick_cdf);
          Eigen::Vector3d acc = Eigen::Vector3d::Zero(), incoming;
          for (int k = 0; k < samples; ++k) {
            const Eigen::Vector3d e =
                m.SampleIrradiance(point, n, options.lighting, sphere_radius, &rng, &incoming,
                                   &rays, brick_cdf, k, samples);
            if (e.isZero()) continue;
            acc += Impl::Brdf(mat, n, incoming, -d).cwiseProduct(e);
          }
          for (int c = 0; c < 3; ++c) sum.at(x, y, c) += static_cast<float>(acc[c]);
        }
      shadow_rays += rays;
      if (pass == 0) surfaces += hits;
    });
    done += samples;
    Progress p;
    p.stage = "render";
    p.unit = "samples";
    p.done = done;
    p.total = options.samples_per_pixel;
    p.values = {{"seconds", Ms(start) / 1000}};
    if (ReportProgress(progress, p)) throw Cancelled("render: cancelled");
  }
  summary.lighting_ms = Ms(t0);
  summary.shadow_rays = shadow_rays;
  summary.surface_pixels = surfaces;

  *linear_rgb = ImageF(width, height, 3, 0.0f);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const std::size_t p = static_cast<std::size_t>(y) * width + x;
      for (int c = 0; c < 3; ++c) {
        const double behind = hit_material[p] >= 0 ? sum.at(x, y, c) / done : m.scene.background[c];
        linear_rgb->at(x, y, c) =
            static_cast<float>(fire_rgb.at(x, y, c) + fire_tr.at(x, y, c) * behind);
      }
    }
  summary.total_ms = Ms(start);
  return summary;
}

}  // namespace flamerig
