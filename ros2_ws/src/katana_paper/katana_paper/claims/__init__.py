"""The paper's claims as statistics: every claim of sections 3.2 and 3.3 evaluated from run
folders, with a bootstrap confidence interval over seeds and a verdict (PASS, FAIL or
INCONCLUSIVE), written as claims.json and claims.md beside the run folder's summary.json.

`stats` holds the numbers (scipy's bootstrap and rank test, the verdict rule, the seeds-to-
decide estimate); `core` a claim's evaluation and the document; `report` the rendering (also
used by docs_report, so the pages show what claims.json says); `abstract` the claims of
section 3.2 from `katana-curiosity paper` folders; `robot` those of section 3.3 from
`katana-robot paper` folders; `cli` the `claims` subcommands of both."""
