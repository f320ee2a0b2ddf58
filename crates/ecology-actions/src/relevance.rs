//! Which atoms can still matter in a state, so that states with the same
//! future are searched (and followed) once.

use crate::task::{AtomId, OpId, State, Task};

/// Which atoms can still matter in a state. An operator that the state
/// cannot reach even in the delete relaxation of every outcome (negative
/// preconditions taken as met) never applies after it; an atom that no
/// reachable operator reads (in its preconditions or what it observes) and
/// the goal does not name can change nothing that follows. Clearing such
/// atoms makes states with the same future one state: in triangle
/// tireworld, which spares are left on roads the car has passed.
pub(crate) struct Relevance {
    /// For each atom, the operators with it in their positive precondition.
    readers: Vec<Vec<u32>>,
    /// The operators with no positive precondition.
    free: Vec<u32>,
    /// Each operator's positive preconditions.
    need: Vec<u32>,
    /// The goal's atoms, positive and negative, as a mask.
    goal: State,
    /// Reused by every call, which runs for every state the planner makes:
    /// preconditions still unmet, atoms reached, atoms relevant, and atoms
    /// to propagate.
    left: Vec<u32>,
    reached: State,
    relevant: State,
    queue: Vec<AtomId>,
}

impl Relevance {
    pub(crate) fn new(task: &Task, excluded: &[bool]) -> Relevance {
        let mut readers = vec![Vec::new(); task.atom_count()];
        let mut free = Vec::new();
        let mut need = Vec::with_capacity(task.operators().len());
        for (i, o) in task.operators().iter().enumerate() {
            need.push(o.pre.len() as u32);
            if excluded[i] {
                // Never fires: one precondition more than it has.
                need[i] += 1;
                continue;
            }
            if o.pre.is_empty() {
                free.push(i as u32);
            }
            for &a in &o.pre {
                readers[a.0 as usize].push(i as u32);
            }
        }
        let mut goal = State::empty(task.atom_count());
        for &a in task.goal().iter().chain(task.goal_neg()) {
            goal.set(a);
        }
        Relevance {
            readers,
            free,
            left: need.clone(),
            need,
            reached: goal.clone(),
            relevant: goal.clone(),
            goal,
            queue: Vec::new(),
        }
    }

    /// Clears the atoms of `state` that cannot matter any more.
    pub(crate) fn clear_irrelevant(&mut self, task: &Task, state: &mut State) {
        let Relevance {
            readers,
            free,
            need,
            goal,
            left,
            reached,
            relevant,
            queue,
        } = self;
        left.clone_from(need);
        reached.clone_from(state);
        relevant.clone_from(goal);
        queue.clear();
        queue.extend(state.atoms());
        let mut fire = |op: u32, reached: &mut State, queue: &mut Vec<AtomId>| {
            let o = task.operator(OpId(op));
            for &a in o.pre.iter().chain(&o.pre_neg).chain(&o.observe) {
                relevant.set(a);
            }
            for (_, add, _) in o.each_outcome() {
                for &a in add {
                    if !reached.holds(a) {
                        reached.set(a);
                        queue.push(a);
                    }
                }
            }
        };
        for &op in free.iter() {
            fire(op, reached, queue);
        }
        while let Some(a) = queue.pop() {
            for &op in &readers[a.0 as usize] {
                left[op as usize] -= 1;
                if left[op as usize] == 0 {
                    fire(op, reached, queue);
                }
            }
        }
        for (w, r) in state.words.iter_mut().zip(&relevant.words) {
            *w &= r;
        }
    }
}
