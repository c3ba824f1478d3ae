from bgap.runner.numerics import command

main = command("bgap.experiments.zoo")
if __name__ == "__main__":
    main()
