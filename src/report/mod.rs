//! Workshop inspection report (issue 6 item 5).
