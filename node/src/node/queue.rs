//! The node's input queue: bounded, drop-oldest, and it remembers what it dropped.

use std::collections::VecDeque;
use std::sync::{Condvar, Mutex};
use std::time::Duration;

use crate::ingest::Route;

/// Bounded FIFO that drops the oldest entry when full and remembers what it dropped.
#[derive(Debug)]
pub struct InputQueue {
    state: Mutex<QueueState>,
    ready: Condvar,
    capacity: usize,
}

#[derive(Debug, Default)]
struct QueueState {
    items: VecDeque<(Route, Vec<u8>)>,
    dropped: Vec<Route>,
}

impl InputQueue {
    pub fn new(capacity: usize) -> Self {
        Self {
            state: Mutex::new(QueueState::default()),
            ready: Condvar::new(),
            capacity: capacity.max(1),
        }
    }

    pub fn push(&self, route: Route, payload: Vec<u8>) {
        let Ok(mut state) = self.state.lock() else {
            return;
        };
        if state.items.len() >= self.capacity {
            if let Some((old, _)) = state.items.pop_front() {
                state.dropped.push(old);
            }
        }
        state.items.push_back((route, payload));
        self.ready.notify_one();
    }

    /// The next item, waiting up to `timeout`; also returns the routes dropped since the last call.
    pub fn pop(&self, timeout: Duration) -> (Option<(Route, Vec<u8>)>, Vec<Route>) {
        let Ok(mut state) = self.state.lock() else {
            return (None, Vec::new());
        };
        if state.items.is_empty() {
            state = match self.ready.wait_timeout(state, timeout) {
                Ok((s, _)) => s,
                Err(_) => return (None, Vec::new()),
            };
        }
        let item = state.items.pop_front();
        (item, std::mem::take(&mut state.dropped))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn queue_drops_oldest_and_reports_it() {
        let queue = InputQueue::new(2);
        queue.push(Route::Tf, vec![1]);
        queue.push(Route::Image(0), vec![2]);
        queue.push(Route::Tf, vec![3]);
        let (item, dropped) = queue.pop(Duration::ZERO);
        assert_eq!(item.unwrap().1, vec![2]);
        assert_eq!(dropped, vec![Route::Tf]);
        let (item, dropped) = queue.pop(Duration::ZERO);
        assert_eq!(item.unwrap().1, vec![3]);
        assert!(dropped.is_empty());
        assert!(queue.pop(Duration::from_millis(1)).0.is_none());
    }
}
