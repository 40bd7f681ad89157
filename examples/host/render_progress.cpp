// A host application's render: its own progress display from RunContext::on_progress, and a Cancel button,
// here a second thread that cancels the job after `seconds` (a UI thread would call cancel() on a click).
// Cancelling stops this job only; the image so far comes back with RunResult::interrupted set.
//   render_progress scene.xml out.exr [seconds=1] [spp=100000]
#include <kelvin/core/error.h>
#include <kelvin/core/image.h>
#include <kelvin/core/job.h>
#include <kelvin/core/parser.h>

#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <thread>

int main(int argc, char** argv) {
    if (argc < 3) {
        std::fprintf(stderr, "usage: %s scene.xml out.exr [seconds] [spp]\n", argv[0]);
        return 2;
    }
    const double seconds = argc > 3 ? std::atof(argv[3]) : 1.0;
    const long long spp = argc > 4 ? std::atoll(argv[4]) : 100000;
    try {
        auto job = std::dynamic_pointer_cast<kelvin::Job>(kelvin::load_scene(argv[1]));
        if (!job) throw kelvin::InputError({argv[1]}, "the scene is not runnable");

        kelvin::RunContext ctx;
        ctx.spp = spp;
        ctx.quiet = true;  // no progress line on stderr: the host shows its own
        int reports = 0;
        double last_done = 0;
        ctx.on_progress = [&](const kelvin::ProgressInfo& p) {  // called from the job's threads, one at a time
            ++reports;
            last_done = p.done;
            std::printf("%s%-10s %3.0f%%  %g/%g %s  %.2f s%s%s\n", p.nested ? "  " : "", p.label.c_str(),
                        100 * p.fraction(), p.done, p.total, p.unit.c_str(), p.seconds, p.final ? "  (done)" : "",
                        p.interrupted ? "  (cancelled)" : "");
        };

        // The "Cancel button": a copy of the job's token, used from another thread.
        kelvin::CancelToken cancel = ctx.cancel;
        std::mutex m;
        std::condition_variable cv;
        bool finished = false;
        std::thread ui([&] {
            std::unique_lock lock(m);
            if (!cv.wait_for(lock, std::chrono::duration<double>(seconds), [&] { return finished; })) {
                std::printf("host: cancelling after %g s\n", seconds);
                cancel.cancel();
            }
        });
        kelvin::RunResult result = job->run(ctx);
        {
            std::lock_guard lock(m);
            finished = true;
        }
        cv.notify_all();
        ui.join();

        kelvin::write_image(argv[2], result.image);
        std::printf("host: %s after %g %s in %.2f s (%d progress reports, last %g); wrote %s\n",
                    result.interrupted ? "cancelled" : "finished", result.work, result.work_unit.c_str(),
                    result.seconds, reports, last_done, argv[2]);
        if (reports < 2) {
            std::fprintf(stderr, "host: expected a start and a final progress report\n");
            return 1;
        }
    } catch (const kelvin::InputError& e) {
        std::fprintf(stderr, "bad scene: %s\n", e.what());
        return 2;
    } catch (const kelvin::Error& e) {
        std::fprintf(stderr, "kelvin: %s\n", e.what());
        return 1;
    }
    return 0;
}
