// Batched rollouts on the persistent thread pool.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <functional>
#include <thread>

#include "reduced_model.h"
#include "thread_pool.h"

namespace softrom {

void ReducedModel::rollout(const StepInputs& in, const std::vector<ReducedState>& starts,
                           const double* controls, int batch, int horizon, int threads,
                           const RolloutOutputs& out) const {
  const int c = static_cast<int>(in.control_basis.cols());
  const Eigen::Index m = basis_cols_;
  const Vec3 d = in.config.direction;
  const double h = in.config.dt;
  // An interrupt is asked for on the calling thread only (the one that holds the Python
  // thread state), between its steps and while it waits for the other workers.
  std::atomic<bool> stop{false};
  const std::thread::id caller = std::this_thread::get_id();
  auto last_poll = std::chrono::steady_clock::now();
  const std::function<void()> poll = [&] {
    last_poll = std::chrono::steady_clock::now();
    if (!stop.load(std::memory_order_relaxed) && (*out.interrupt)()) stop.store(true);
  };
  // Each rollout is computed start to finish by one worker, in a workspace it holds for the
  // rollout, so results do not depend on the thread count or the schedule.
  auto run = [&](int b) {
    const WorkspaceLease lease = lend_workspace();
    Workspace& ws = *lease;
    ReducedState s = starts[starts.size() == 1 ? 0 : b];
    bool bad = false, converged = true;
    int good = horizon;
    const bool polls = out.interrupt && std::this_thread::get_id() == caller;
    for (int t = 0; t < horizon; ++t) {
      if (out.interrupt) {
        if (polls && std::chrono::steady_clock::now() - last_poll >= ThreadPool::kPollInterval)
          poll();
        if (stop.load(std::memory_order_relaxed)) return;
      }
      const size_t bt = static_cast<size_t>(b) * horizon + t;
      double reward = 0.0;
      if (!bad) {
        const StepInfo info = step(in, s, controls + bt * c, ws);
        bad = info.diverged;
        if (bad) good = t;
        converged = converged && info.converged && info.contact_converged;
        if (!bad) reward = d.dot(com_velocity(s.qdot)) * h;
      }
      out.rewards[bt] = reward;
      if (out.com) {
        const Vec3 p = com(s.q);
        std::copy(p.data(), p.data() + 3, out.com + bt * 3);
      }
      if (out.observe && out.observed) {
        // Linear observables of q_r per step (e.g. the linearised orientation).
        const Eigen::Index no = out.observe->rows();
        Eigen::Map<VecX>(out.observed + bt * no, no).noalias() = (*out.observe) * s.q;
      }
    }
    std::copy(s.q.data(), s.q.data() + m, out.final_q + static_cast<size_t>(b) * m);
    std::copy(s.qdot.data(), s.qdot.data() + m, out.final_qdot + static_cast<size_t>(b) * m);
    const Eigen::Index ni = s.impulses.size();
    std::copy(s.impulses.data(), s.impulses.data() + ni,
              out.final_impulses + static_cast<size_t>(b) * ni);
    out.diverged[b] = bad ? 1 : 0;
    if (out.good_steps) out.good_steps[b] = good;
    // (A diverged rollout's later steps were never solved, whatever its last step's flags.)
    if (out.converged) out.converged[b] = converged && !bad ? 1 : 0;
  };
  threads = std::max(1, std::min(threads, batch));
  if (threads == 1) {
    for (int b = 0; b < batch; ++b) run(b);
    return;
  }
  ThreadPool::instance().run(threads, batch, run, out.interrupt ? &poll : nullptr);
}

}  // namespace softrom
